"""The web app's edit API (``POST /api/edit``, through ``t2m.edit``) against a real server on a
free port of 127.0.0.1 with the tiny checkpoints: every mode, sources uploaded or generated,
equality with the library, downloads of edits, and every bad input in words."""

from __future__ import annotations

import base64
import io
import socket

import numpy as np
import pytest
from conftest import synth_joints
from test_serve import call

from dataset_tools.bvh import write_bvh
from t2m.edit import edit as library_edit
from t2m.edit import prepare_source

LOWER = [0, 1, 2, 4, 5, 7, 8, 10, 11]


@pytest.fixture(scope="module")
def walk() -> np.ndarray:
    return synth_joints("walk_forward", 101, np.random.default_rng(3))


def _upload(name: str, data: bytes) -> dict:
    return {"upload": {"name": name, "base64": base64.b64encode(data).decode()}}


def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def _kept(motion: dict) -> np.ndarray:
    return np.array([[c == "1" for c in row] for row in motion["kept"]])


def _joints(motion: dict) -> np.ndarray:
    return np.asarray(motion["joints"]).reshape(motion["frames"], 22, 3)


def test_info_offers_every_mode(server):
    info = call(server, "GET", "/api/info")[1]["edit"]
    assert info["available"] is True
    assert info["modes"] == ["continue", "inbetween", "body", "path", "keys", "compose"]
    assert "lower" in info["parts"] and info["highlight_color"].startswith("#")


def test_continue_an_uploaded_npy_is_what_the_library_makes(server, pipe, walk):
    body = {"mode": "continue", "text": "a person walks forward", "keep_seconds": 1.5}
    body.update(seconds=4.0, samples=2, seed=5, source=_upload("walk.npy", _npy(walk)))
    status, answer, _ = call(server, "POST", "/api/edit", body)
    assert status == 200, answer
    assert answer["edit"] == {"mode": "continue", "source": "walk.npy"}
    expected = library_edit(
        pipe, "a person walks forward", "continue", walk, keep_seconds=1.5, seconds=4.0,
        num_samples=2, seed=5,
    )  # fmt: skip
    source = prepare_source(walk)
    for motion, reference in zip(answer["motions"], expected):
        assert motion["frames"] == 80
        kept = _kept(motion)
        assert kept[:30].all() and not kept[30:].any()
        np.testing.assert_allclose(_joints(motion)[:30], source.joints[:30], atol=2e-4)
        np.testing.assert_allclose(_joints(motion), reference.joints, atol=2e-4)
    assert not [p for p in server.app.store.root.iterdir() if p.name.startswith(".upload")]


def test_body_of_an_uploaded_bvh_and_of_a_generated_motion(server, walk, tmp_path):
    write_bvh(walk, tmp_path / "walk.bvh")
    body = {"mode": "body", "text": "a person raises the left arm", "part": "lower"}
    body["source"] = _upload("walk.bvh", (tmp_path / "walk.bvh").read_bytes())
    status, answer, _ = call(server, "POST", "/api/edit", body)
    assert status == 200, answer
    kept = _kept(answer["motions"][0])
    assert kept[:, LOWER].all() and not kept[:, 20].any()
    # a motion this server generated, named by its request id and index
    generated = call(server, "POST", "/api/generate", {"prompts": ["a person walks#60"]})[1]
    body["source"] = {"result": generated["id"], "motion": 0}
    status, answer, _ = call(server, "POST", "/api/edit", body)
    assert status == 200, answer
    assert answer["motions"][0]["frames"] == 56  # whole snippets of the 59 feature frames
    # downloads of an edit are there as for a generation
    status, data, _ = call(server, "GET", answer["motions"][0]["files"]["bvh"])
    assert status == 200 and data.startswith(b"HIERARCHY")


def test_path_keys_inbetween_and_compose(server, walk):
    path = [[1.0, 0.3, 0.8], [2.5, 0.5, 2.0]]
    status, answer, _ = call(
        server,
        "POST",
        "/api/edit",
        {"mode": "path", "text": "a person walks forward", "path": path},
    )
    assert status == 200, answer
    joints = _joints(answer["motions"][0])
    for t, x, z in path:
        np.testing.assert_allclose(joints[round(t * 20), 0, [0, 2]], [x, z], atol=2e-3)
    keys = np.full((40, 22, 3), np.nan, np.float32)
    keys[30, 0, [0, 2]] = [0.2, 0.9]
    body = {"mode": "keys", "text": "a person walks forward", "keys": _upload("k.npy", _npy(keys))}
    status, answer, _ = call(server, "POST", "/api/edit", body)
    assert status == 200, answer
    np.testing.assert_allclose(_joints(answer["motions"][0])[30, 0, [0, 2]], [0.2, 0.9], atol=2e-3)
    body = {"mode": "inbetween", "text": "a person jumps up and down", "keep_start": 1.0}
    body.update(keep_end=1.0, source=_upload("walk.npy", _npy(walk)))
    status, answer, _ = call(server, "POST", "/api/edit", body)
    assert status == 200, answer
    kept = _kept(answer["motions"][0])
    assert kept[:20].all() and kept[-20:].all() and not kept[20:-20].any()
    timeline = ["a person walks forward#0#3", "a person jumps up and down#3"]
    status, answer, _ = call(server, "POST", "/api/edit", {"mode": "compose", "timeline": timeline})
    assert status == 200, answer
    assert answer["motions"][0]["frames"] == 120
    assert answer["motions"][0]["text"] == "a person walks forward / a person jumps up and down"


def _walk_upload() -> dict:
    return _upload("walk.npy", _npy(synth_joints("walk_forward", 61, np.random.default_rng(1))))


BAD_EDITS = [
    ({"mode": "dance", "text": "a person walks"}, "mode must be one of"),
    ({"mode": "continue", "text": "a person walks"}, "upload a BVH or .npy, or pick a motion"),
    ({"mode": "continue", "text": "", "source": "SOURCE"}, "empty edit text"),
    ({"mode": "continue", "text": "qwzx blorf", "source": "SOURCE"}, "no known word"),
    (
        {"mode": "path", "text": "a person walks", "source": "SOURCE", "path": [[1, 0, 0]]},
        "takes no source",
    ),
    (
        {"mode": "continue", "text": "a person walks", "source": "/etc/passwd"},
        "must be an uploaded file",
    ),
    (
        {
            "mode": "continue",
            "text": "a person walks",
            "source": {"upload": {"name": "a.npy", "base64": "%%%"}},
        },
        "not valid base64",
    ),
    (
        {
            "mode": "continue",
            "text": "a person walks",
            "source": {"upload": {"name": "a.txt", "base64": "aGk="}},
        },
        "must be a .bvh or .npy file",
    ),
    (
        {
            "mode": "continue",
            "text": "a person walks",
            "source": {"upload": {"name": "a.npy", "base64": ""}},
        },
        "the uploaded a.npy",
    ),
    (
        {
            "mode": "continue",
            "text": "a person walks",
            "source": {"upload": {"name": "a.bvh", "base64": "aGk="}},
        },
        "the uploaded a.bvh",
    ),
    (
        {"mode": "continue", "text": "a person walks", "source": {"result": "A" * 22, "motion": 0}},
        "no such generated motion",
    ),
    (
        {"mode": "continue", "text": "a person walks", "source": "SOURCE", "keep_seconds": -1},
        "keep_seconds must be from 0",
    ),
    (
        {"mode": "continue", "text": "a person walks", "source": "SOURCE", "keep_seconds": "2"},
        "keep_seconds must be a number",
    ),
    (
        {"mode": "continue", "text": "a person walks", "source": "SOURCE", "seconds": 99},
        "seconds must be from 0",
    ),
    (
        {"mode": "body", "text": "a person walks", "source": "SOURCE", "part": "tail"},
        "part must be one of",
    ),
    (
        {"mode": "path", "text": "a person walks", "path": "/etc/passwd"},
        "path must be 1 to 100 rows",
    ),
    ({"mode": "path", "text": "a person walks", "path": [[1, 0]]}, "rows of three numbers"),
    ({"mode": "path", "text": "a person walks", "path": [[2, 0, 0], [1, 0, 1]]}, "increasing"),
    (
        {
            "mode": "keys",
            "text": "a person walks",
            "keys": {"upload": {"name": "k.npy", "base64": "aGk="}},
        },
        "the uploaded k.npy",
    ),
    ({"mode": "compose", "timeline": "/etc/passwd"}, "'text#start#end'"),
    ({"mode": "compose", "timeline": ["a person walks#0#3", "a person jumps#4#6"]}, "a gap"),
    ({"mode": "compose", "timeline": ["a person walks#10"] * 9}, "1 to 8 lines"),
    (
        {"mode": "compose", "timeline": ["a person walks#20", "a person jumps#20"]},
        "longer than 30 s",
    ),
    (
        {"mode": "continue", "text": "a person walks", "source": "SOURCE", "samples": 9},
        "samples must be from 1 to 8",
    ),
    (
        {"mode": "continue", "text": "a person walks", "source": "SOURCE", "extra": 1},
        "unknown field 'extra'",
    ),
]


@pytest.mark.parametrize(("body", "words"), BAD_EDITS)
def test_bad_edits_are_refused_in_words(server, body, words):
    body = {key: _walk_upload() if value == "SOURCE" else value for key, value in body.items()}
    status, answer, _ = call(server, "POST", "/api/edit", body)
    assert status == 400, answer
    assert words in answer["error"] and "\n" not in answer["error"], answer["error"]
    assert ".upload-" not in answer["error"] and str(server.app.store.root) not in answer["error"]
    assert not [p for p in server.app.store.root.iterdir() if p.name.startswith(".upload")]


def test_an_edit_body_may_be_larger_than_a_generate_body(server):
    big = {"mode": "continue", "text": "a person walks", "source": _upload("a.npy", b"x" * 200_000)}
    status, answer, _ = call(server, "POST", "/api/edit", big)
    assert status == 400 and "the uploaded a.npy" in answer["error"]  # read, then refused
    # past the limit the server answers from the headers, without reading the body
    with socket.create_connection(server.server_address[:2], timeout=30) as connection:
        connection.sendall(
            b"POST /api/edit HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            b"Content-Length: 7000000\r\n\r\n"
        )
        reply = connection.makefile("rb").read().decode()
    assert reply.startswith("HTTP/1.0 400") and "at most 6291456" in reply
