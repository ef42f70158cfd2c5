"""Hostile inputs to the web app's server (issue 31, second round), against a real server on a
free port of 127.0.0.1 with the tiny checkpoints. Each case once failed: a 500, an answer without
the security headers, a request accepted that should not be, or memory without bound.

Cases per area:

* no input gives a 500 (4 cases): a path time of 1e308, a 400-digit integer in a path, JSON
  nested 100,000 levels deep, a Content-Length of non-ASCII digits;
* every answer carries the security headers (5 cases): OPTIONS, PUT, DELETE, an invented
  method, a malformed request line;
* a request with two Host headers is refused (1 case);
* sizes a tiny request implies are bounded before work (1 case): a 7 KB BVH whose frame time
  makes it hours long at the model's frame rate.
"""

from __future__ import annotations

import base64
import json
import socket

import numpy as np
import pytest
from conftest import synth_joints  # tests/ is on the path (it has no __init__.py)
from test_serve import call

from dataset_tools.bvh import write_bvh
from t2m.pipeline import TextToMotion
from t2m.serve import api
from t2m.serve.server import SECURITY_HEADERS, make_server


@pytest.fixture(scope="module")
def pipe(tiny_run):
    return TextToMotion.from_checkpoints(tiny_run, device="cpu")


@pytest.fixture(scope="module")
def server(pipe, tiny_run, tmp_path_factory):
    server = make_server(pipe, str(tiny_run), port=0, work_dir=tmp_path_factory.mktemp("work"))
    server.start_in_thread()
    yield server
    server.shutdown_app()


def raw_request(server, data: bytes) -> tuple[int, dict[str, str], bytes]:
    """Send ``data`` as it is; (status, headers with lower-case names, body) of the answer."""
    host, port = server.server_address[:2]
    with socket.create_connection((host, port), timeout=60) as connection:
        connection.sendall(data)
        connection.shutdown(socket.SHUT_WR)
        answer = b""
        while chunk := connection.recv(65536):
            answer += chunk
    head, _, body = answer.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {}
    for line in lines[1:]:
        name, _, value = line.partition(":")
        headers[name.strip().lower()] = value.strip()
    return status, headers, body


def _path_edit(path: list) -> dict:
    return {"mode": "path", "text": "a person walks forward", "path": path}


# -- no input gives a 500 ----------------------------------------------------------------------


def test_a_path_time_of_1e308_is_a_400(server):
    status, answer, _ = call(
        server, "POST", "/api/edit", _path_edit([[1.0, 0, 0.5], [1e308, 1, 1]])
    )
    assert status == 400, answer
    assert answer["error"].startswith("path row 2: the time must be from 0 to")


def test_a_400_digit_integer_in_a_path_is_a_400(server):
    raw = json.dumps(_path_edit([[1, 0, 0.5], [2, 12345, 1]])).replace("12345", "9" * 400)
    status, answer, _ = call(server, "POST", "/api/edit", raw=raw.encode())
    assert status == 400, answer
    assert answer["error"].startswith("path row 2: x and z must be from")


def test_json_nested_100000_levels_is_a_400(server):
    raw = b"[" * 100_000 + b"]" * 100_000
    status, answer, _ = call(server, "POST", "/api/edit", raw=raw)
    assert status == 400, answer
    assert "JSON" in answer["error"]


@pytest.mark.parametrize("length", ["١٢".encode(), b"\xb2"], ids=["arabic-indic", "superscript"])
def test_a_content_length_of_non_ascii_digits_is_a_400(server, length):
    data = (
        b"POST /api/generate HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
        b"Content-Length: " + length + b"\r\n\r\n" + b'{"prompts": ["a person walks"]}'
    )
    status, headers, body = raw_request(server, data)
    assert status == 400, body
    assert b"Content-Length" in body


# -- every answer carries the security headers --------------------------------------------------


@pytest.mark.parametrize("method", ["OPTIONS", "PUT", "DELETE", "BREW"])
def test_unhandled_methods_answer_with_the_security_headers(server, method):
    data = f"{method} /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 0\r\n\r\n"
    status, headers, body = raw_request(server, data.encode())
    assert 400 <= status < 500 or status == 501, body
    for name, value in SECURITY_HEADERS.items():
        assert headers.get(name.lower()) == value, (name, headers)
    assert headers["content-type"].startswith("application/json")


def test_a_malformed_request_line_answers_with_the_security_headers(server):
    status, headers, body = raw_request(server, b"GET / HTTP/1.1 extra words\r\n\r\n")
    assert status == 400, body
    assert headers.get("content-security-policy") == SECURITY_HEADERS["Content-Security-Policy"]
    assert headers.get("x-content-type-options") == "nosniff"


# -- two Host headers ---------------------------------------------------------------------------


def test_two_host_headers_are_refused(server):
    data = b"GET /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: evil.example\r\n\r\n"
    status, headers, body = raw_request(server, data)
    assert status == 400, body
    assert b"Host" in body
    assert headers.get("x-content-type-options") == "nosniff"


# -- sizes a tiny request implies ---------------------------------------------------------------


def test_a_bvh_hours_long_at_the_model_rate_is_refused_before_work(server, tmp_path):
    walk = synth_joints("walk_forward", 10, np.random.default_rng(3))
    write_bvh(walk, tmp_path / "walk.bvh")
    text = (tmp_path / "walk.bvh").read_text()
    head, _, frames = text.partition("Frame Time:")
    slow = head + "Frame Time: 100000" + "\n" + frames.split("\n", 1)[1]
    assert len(slow) < 16_000
    upload = {"upload": {"name": "slow.bvh", "base64": base64.b64encode(slow.encode()).decode()}}
    body = {"mode": "body", "text": "a person waves", "part": "lower", "source": upload}
    status, answer, _ = call(server, "POST", "/api/edit", body)
    assert status == 400, answer
    limit = api.Limits().max_source_frames
    assert "slow.bvh" in answer["error"] and f"{limit}" in answer["error"]
