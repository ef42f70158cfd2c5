"""The web app's server (``python -m t2m.serve``): the JSON API against a real server on a free
port of 127.0.0.1 with the tiny checkpoints, downloads, every bad input, concurrent requests and
batching, file cleanup, and the command line."""

from __future__ import annotations

import http.client
import json
import math
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from dataset_tools.bvh import motion_from_joints
from dataset_tools.skeleton import SMPL
from dataset_tools.sources.bvh import BvhOptions, load_bvh_motion
from t2m.serve import api
from t2m.serve.results import Expired, ResultStore
from t2m.serve.server import ROUTES, find_route, is_loopback, make_server
from t2m.serve.worker import GenerationJob, GenerationWorker, generate_jobs

REPO = Path(__file__).resolve().parents[1]


def call(server, method: str, path: str, body=None, headers=None, raw: bytes | None = None):
    """(status, parsed JSON or raw bytes, headers) of one request to the server."""
    host, port = server.server_address[:2]
    connection = http.client.HTTPConnection(host, port, timeout=120)
    sent = raw if raw is not None else (None if body is None else json.dumps(body).encode())
    all_headers = {"Content-Type": "application/json", **(headers or {})}
    connection.request(method, path, body=sent, headers=all_headers)
    response = connection.getresponse()
    data = response.read()
    connection.close()
    if response.getheader("Content-Type", "").startswith("application/json"):
        return response.status, json.loads(data), response
    return response.status, data, response


def test_info_describes_the_model_and_limits(server):
    status, info, _ = call(server, "GET", "/api/info")
    assert status == 200
    assert (info["fps"], info["min_frames"], info["max_frames"]) == (20.0, 40, 196)
    assert info["skeleton"]["parents"] == list(SMPL.parents)
    assert info["skeleton"]["colors"]["left"] == "#1f6fd1"
    assert sorted(set(info["skeleton"]["sides"])) == ["center", "left", "right"]
    assert info["limits"]["max_prompts"] == api.Limits().max_prompts
    assert info["automatic_length"] is True and "int8" in info["precisions"]
    assert info["edit"]["available"] in (True, False) and info["edit"].get("reason", "x")


def test_the_page_and_its_files_are_served(server):
    status, page, response = call(server, "GET", "/")
    assert status == 200 and b'id="generate"' in page
    assert "default-src 'self'" in response.getheader("Content-Security-Policy")
    for name in ("app.js", "viewer.js", "style.css"):
        status, _, _ = call(server, "GET", f"/static/{name}")
        assert status == 200, name


def test_the_page_is_es_modules_served_as_javascript(server):
    """index.html loads one entry module; every module it reaches is served with a JavaScript
    type (browsers refuse modules otherwise) under the same policy, and none writes a global."""
    _, page, _ = call(server, "GET", "/")
    entries = re.findall(rb'<script type="module" src="/static/([\w.]+)"></script>', page)
    assert entries == [b"app.js"] and b"<script src" not in page
    seen, todo = set(), ["app.js"]
    while todo:
        name = todo.pop()
        status, source, response = call(server, "GET", f"/static/{name}")
        assert status == 200, name
        assert response.getheader("Content-Type") == "text/javascript; charset=utf-8", name
        assert "default-src 'self'" in response.getheader("Content-Security-Policy")
        text = source.decode()
        assert not re.search(r"\bwindow\.\w+\s*=", text), f"{name} writes a global"
        seen.add(name)
        todo += [m for m in re.findall(r'from "\./([\w.]+)"', text) if m not in seen]
    assert seen == {"app.js", "api.js", "dom.js", "edit.js", "live.js", "player.js", "viewer.js"}
    status, answer, response = call(server, "HEAD", "/static/viewer.js")
    assert status == 200 and answer == b"" and response.getheader("Content-Length") != "0"


def test_the_route_table():
    route, params = find_route("GET", "/api/files/abc/results.json")
    assert route.handler.__name__ == "get_download"
    assert params == {"request_id": "abc", "name": "results.json"}
    assert find_route("HEAD", "/")[0].handler.__name__ == "get_page"
    assert find_route("POST", "/api/edit")[0].handler.__name__ == "post_edit"
    for method, path in [
        ("GET", "/api/edit"),
        ("POST", "/api/info"),
        ("GET", "/static/"),
        ("GET", "/static/a/b.js"),
        ("GET", "/api/results/"),
        ("GET", "/api/files/abc"),
    ]:
        assert find_route(method, path) == (None, {}), (method, path)
    assert {(r.method, r.path) for r in ROUTES} >= {("GET", "/api/info"), ("POST", "/api/generate")}


def test_generate_returns_joints_and_links_that_match_the_library(server, pipe):
    body = {"prompts": ["a person walks forward#48", "someone jumps up and down"]}
    body.update(seconds=2.4, samples=2, seed=7)
    status, answer, _ = call(server, "POST", "/api/generate", body)
    assert status == 200, answer
    assert re.fullmatch(r"[A-Za-z0-9_-]{22}", answer["id"])
    assert [m["frames"] for m in answer["motions"]] == [48, 48, 48, 48]
    assert [(m["prompt"], m["sample"]) for m in answer["motions"]] == [
        (0, 0),
        (0, 1),
        (1, 0),
        (1, 1),
    ]
    # the same seed gives what the Python API gives for the same prompts and lengths
    expected = pipe.generate(
        ["a person walks forward", "someone jumps up and down"], 2, [48, 48], seed=7
    )
    for motion in answer["motions"]:
        joints = np.asarray(motion["joints"]).reshape(motion["frames"], 22, 3)
        reference = expected[motion["prompt"]][motion["sample"]].joints
        np.testing.assert_allclose(joints, reference, atol=2e-4)
    assert set(answer["motions"][0]["files"]) == {"npy", "bvh", "glb", "mp4", "gif"}
    assert answer["prompts"][1]["unknown_words"] == []
    # a drawn length (no seconds, no #) comes from text2length: a multiple of 4 in 40..196
    status, drawn, _ = call(server, "POST", "/api/generate", {"prompts": ["a person walks"]})
    assert status == 200 and drawn["motions"][0]["frames"] % 4 == 0
    assert 40 <= drawn["motions"][0]["frames"] <= 196
    # history: the answer again by id
    status, again, _ = call(server, "GET", f"/api/results/{answer['id']}")
    assert status == 200 and again["motions"][3]["joints"] == answer["motions"][3]["joints"]


def test_downloads_are_the_motions(server):
    body = {"prompts": ["a person walks forward#40"], "samples": 2, "seed": 3}
    _, answer, _ = call(server, "POST", "/api/generate", body)
    motion = answer["motions"][1]
    joints = np.asarray(motion["joints"]).reshape(-1, 22, 3)
    status, data, response = call(server, "GET", motion["files"]["npy"])
    assert status == 200 and "sample00_rep01.npy" in response.getheader("Content-Disposition")
    path = Path(server.app.store.root) / answer["id"] / "sample00_rep01.npy"
    np.testing.assert_allclose(np.load(path), joints, atol=1e-4)
    status, data, _ = call(server, "GET", motion["files"]["bvh"])
    assert status == 200 and data.startswith(b"HIERARCHY")
    # our BVH importer reads it back into the skeleton motion the writer solved
    imported = load_bvh_motion(path.with_suffix(".bvh"), BvhOptions())
    assert imported.fps == pytest.approx(20.0) and imported.joints.shape == (40, 22, 3)
    solved = motion_from_joints(np.load(path)).joints()
    assert np.linalg.norm(imported.joints - solved, axis=-1).max() < 0.01
    status, data, response = call(server, "GET", motion["files"]["glb"])
    assert status == 200 and data[:4] == b"glTF"
    assert response.getheader("Content-Type") == "model/gltf-binary"
    status, data, _ = call(server, "GET", motion["files"]["gif"])
    assert status == 200 and data[:6] == b"GIF89a"
    status, data, _ = call(server, "GET", answer["files"]["results.npy"])
    results = np.load(Path(server.app.store.root) / answer["id"] / "results.npy", allow_pickle=True)
    assert status == 200 and results.item()["motion"].shape == (2, 22, 3, 40)
    status, summary, _ = call(server, "GET", answer["files"]["results.json"])
    assert status == 200 and summary["seed"] == 3 and "sample00_rep01.npy" in summary["files"]


LONG = "walk " * 70
BAD_REQUESTS = [
    ({"prompts": [""]}, "empty prompt"),
    ({"prompts": ["   ", ""]}, "empty prompt"),
    ({}, "prompts must be"),
    ({"prompts": 5}, "prompts must be"),
    ({"prompts": [1, 2]}, "prompts must be"),
    ({"prompts": ["a person walks"] * 9}, "at most 8"),
    ({"prompts": [LONG]}, "characters; at most 300"),
    ({"prompts": ["a person\x07 walks"]}, "control characters"),
    ({"prompts": ["qwzx blorf"]}, "no known word"),
    ({"prompts": ["a person walks#abc"]}, "after '#' give a length in frames"),
    ({"prompts": ["#40"]}, "empty prompt before"),
    ({"prompts": ["a person walks#10"]}, "out of range"),
    ({"prompts": ["a person walks#400"]}, "out of range"),
    ({"prompts": ["a person walks"], "seconds": 0.5}, "out of range"),
    ({"prompts": ["a person walks"], "seconds": 100}, "out of range"),
    ({"prompts": ["a person walks"], "seconds": "5"}, "seconds must be a number"),
    ({"prompts": ["a person walks"], "samples": 0}, "samples must be from 1 to 8"),
    ({"prompts": ["a person walks"], "samples": 9}, "samples must be from 1 to 8"),
    ({"prompts": ["a person walks"], "samples": "3"}, "samples must be a whole number"),
    ({"prompts": ["a person walks"], "samples": True}, "samples must be a whole number"),
    ({"prompts": ["a person walks"] * 5, "samples": 7}, "at most 32"),
    ({"prompts": ["a person walks"], "seed": -1}, "seed must be from 0"),
    ({"prompts": ["a person walks"], "seed": 2**31}, "seed must be from 0"),
    ({"prompts": ["a person walks"], "seed": 1.5}, "seed must be a whole number"),
    ({"prompts": ["a person walks"], "precision": "fp16"}, "precision must be one of"),
    ({"prompts": ["a person walks"], "lengths": [40]}, "unknown field 'lengths'"),
    # the schema's fields the web does not take: the command line's literal --text, its name
    # of samples, its length in frames
    ({"prompts": ["a person walks"], "text": "a person walks"}, "unknown field 'text'"),
    ({"prompts": ["a person walks"], "num_samples": 2}, "unknown field 'num_samples'"),
    ({"prompts": ["a person walks"], "length": 40}, "unknown field 'length'"),
    ([1, 2], "must be a JSON object"),
]


@pytest.mark.parametrize(("body", "words"), BAD_REQUESTS)
def test_bad_generate_requests_are_refused_in_words(server, body, words):
    status, answer, _ = call(server, "POST", "/api/generate", body)
    assert status == 400
    assert words in answer["error"], answer["error"]
    assert "\n" not in answer["error"]


def test_a_generate_request_is_the_generation_schema_plus_the_web_limits(pipe):
    from dataset_tools.command import UsageError
    from t2m.prompts import Prompt
    from t2m.request import GenerationRequest

    body = {"prompts": "a person walks#48\n\nsomeone jumps", "seconds": 3, "samples": 2}
    checked = api.parse_generate({**body, "seed": 5}, pipe.spec, True, api.Limits(), "cpu")
    assert checked.request == GenerationRequest(
        prompts=("a person walks#48", "someone jumps"), seconds=3.0, num_samples=2, seed=5
    )
    assert checked.prompts == (Prompt("a person walks", 48), Prompt("someone jumps", 60))
    assert checked.precision == "fp32"
    # the edit's samples, seed and precision are read by the same types and limits
    assert api.run_options({"mode": "body", "samples": 2, "seed": 5}, api.Limits(), "cpu") == (
        2,
        5,
        "fp32",
    )
    with pytest.raises(UsageError, match="^samples must be a whole number; got '2'$"):
        api.run_options({"mode": "body", "samples": "2"}, api.Limits(), "cpu")


def test_bad_bodies_routes_and_hosts(server):
    generate = "/api/generate"
    status, answer, _ = call(server, "POST", generate, raw=b"{not json")
    assert (status, answer["error"]) == (
        400,
        "the request body is not valid JSON (line 1, "
        "column 2: Expecting property name enclosed in double quotes)",
    )
    status, answer, _ = call(server, "POST", generate, raw=b'{"seconds": NaN}')
    assert status == 400
    status, answer, _ = call(
        server, "POST", generate, raw=b"{}", headers={"Content-Type": "text/plain"}
    )
    assert status == 400 and "JSON" in answer["error"]
    status, answer, _ = call(server, "POST", generate, raw=b" " * (64 * 1024 + 1))
    assert status == 400 and "at most 65536" in answer["error"]
    assert call(server, "GET", generate)[0] == 405
    status, answer, _ = call(server, "GET", "/api/edit")
    assert (status, answer["error"]) == (405, "/api/edit takes POST")
    assert call(server, "GET", "/api/nothing")[0] == 404
    status, answer, _ = call(server, "POST", "/api/info", raw=b"{}")
    assert (status, answer["error"]) == (404, "no such page or file: /api/info")
    status, answer, _ = call(server, "GET", "/api/info", headers={"Host": "evil.example:80"})
    assert status == 403 and "localhost" in answer["error"]
    assert call(server, "GET", "/api/info", headers={"Host": "localhost:1"})[0] == 200


def test_downloads_refuse_traversal_and_other_names(server):
    _, answer, _ = call(server, "POST", "/api/generate", {"prompts": ["a person walks#40"]})
    request_id = answer["id"]
    secret = Path(server.app.store.root) / "secret.txt"
    secret.write_text("not for downloading")
    for path in [
        f"/api/files/{request_id}/../secret.txt",
        f"/api/files/{request_id}/..%2fsecret.txt",
        f"/api/files/{request_id}/%2e%2e/secret.txt",
        f"/api/files/..%2f{request_id}/results.json",
        f"/api/files/{request_id}/sample00_rep00_feats.npy",
        f"/api/files/{request_id}/sample00_rep01.npy",  # one sample only
        f"/api/files/{request_id}/sample01_rep00.bvh",  # one prompt only
        f"/api/files/{request_id}/.t2m-sample.json",
        f"/api/files/{'A' * 22}/results.json",  # the right shape, no such request
        "/api/files/secret.txt/results.json",
        "/static/../server.py",
        "/static/%2e%2e%2fserver.py",
        f"/api/results/{request_id[:-1]}",
    ]:
        status, data, _ = call(server, "GET", path)
        assert status == 404, path
        assert b"not for downloading" not in json.dumps(data).encode()
    ids = {call(server, "POST", "/api/generate", {"prompts": ["a person walks#40"]})[1]["id"]}
    ids.add(request_id)
    assert len(ids) == 2  # a new random name for every request


def test_concurrent_requests_each_get_their_own_motions(server, pipe):
    """Eight clients at once; each answer is what that seed gives alone."""
    answers: dict[int, dict] = {}

    def client(seed: int) -> None:
        body = {"prompts": ["a person walks forward#44"], "samples": 2, "seed": seed}
        status, answer, _ = call(server, "POST", "/api/generate", body)
        assert status == 200, answer
        answers[seed] = answer

    threads = [threading.Thread(target=client, args=(seed,)) for seed in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=120)
    assert sorted(answers) == list(range(8))
    for seed, answer in answers.items():
        expected = pipe.generate("a person walks forward", 2, 44, seed=seed)
        for motion in answer["motions"]:
            joints = np.asarray(motion["joints"]).reshape(44, 22, 3)
            np.testing.assert_allclose(joints, expected[0][motion["sample"]].joints, atol=2e-4)
    assert len({json.dumps(a["motions"][0]["joints"]) for a in answers.values()}) == 8


def test_batching_requests_gives_each_what_it_gets_alone(pipe):
    jobs = [
        GenerationJob(["a person walks forward"], [None], 3, seed=1, precision="fp32"),
        GenerationJob(["someone jumps up and down", "a person turns"], [60, 100], 1, 2, "fp32"),
        GenerationJob(["qwzx"], [40], 1, seed=3, precision="fp32"),  # refused, the others run
        # generated clause by clause, as pipe.generate does by default
        GenerationJob(["a person walks forward, then jumps up and down"], [96], 2, 4, "fp32"),
    ]
    generate_jobs(pipe, jobs)
    assert "no known word" in str(jobs[2].error)
    for job in (jobs[0], jobs[1], jobs[3]):
        alone = pipe.generate(job.texts, job.num_samples, job.frames, seed=job.seed)
        for row, expected in zip(job.result[0], alone):
            for motion, reference in zip(row, expected):
                assert motion.num_frames == reference.num_frames
                np.testing.assert_allclose(motion.joints, reference.joints, atol=1e-4)


def test_worker_batches_what_waits_and_refuses_a_full_queue(pipe):
    worker = GenerationWorker(pipe, max_batch_motions=4, max_queue=3)
    worker.stop()  # nothing runs: jobs wait in the queue
    jobs = [GenerationJob(["a person walks"], [40], 2, seed, "fp32") for seed in range(3)]
    for job in jobs:
        worker.submit(job)
    with pytest.raises(queue.Full):
        worker.submit(GenerationJob(["a person walks"], [40], 1, 9, "fp32"))
    assert [len(worker._next_batch()), len(worker._next_batch())] == [2, 1]  # 4 motions a batch


def test_busy_server_answers_503(pipe, tiny_run, tmp_path):
    server = make_server(pipe, str(tiny_run), port=0, work_dir=tmp_path, max_queue=1)
    server.app.worker.stop()
    server.app.generate_timeout = 0.3
    server.start_in_thread()
    try:
        body = {"prompts": ["a person walks#40"]}
        status, answer, _ = call(server, "POST", "/api/generate", body)
        assert status == 503 and "too long" in answer["error"]
        status, answer, _ = call(server, "POST", "/api/generate", body)
        assert status == 503 and "busy" in answer["error"]
    finally:
        server.shutdown_app()


def test_files_are_removed_after_their_time_or_past_the_size(pipe, tmp_path):
    motions = pipe.generate("a person walks", 1, 40, seed=0)
    store = ResultStore(tmp_path / "work", 20.0, keep_seconds=60, max_bytes=10**9)
    old, new = store.add(motions, 0, {}), store.add(motions, 0, {})
    old.created -= 61
    assert store.clean() == [old.id]
    assert not old.folder.exists() and new.folder.exists()
    with pytest.raises(Expired):
        store.file(old.id, "results.json")
    store.max_bytes = new.size() + 1  # room for one request: the older goes first
    newest = store.add(motions, 0, {})
    assert not new.folder.exists() and newest.folder.exists()
    store.max_bytes = 1  # the newest request always stays
    assert store.clean() == [] and newest.folder.exists()
    store.close()
    assert not newest.folder.exists()


def test_expired_download_is_gone_in_words(server):
    _, answer, _ = call(server, "POST", "/api/generate", {"prompts": ["a person walks#40"]})
    server.app.store.get(answer["id"]).created -= server.app.store.keep_seconds + 1
    status, error, _ = call(server, "GET", answer["files"]["results.json"])
    assert status == 410 and "removed" in error["error"]
    assert call(server, "GET", f"/api/results/{answer['id']}")[0] == 410


def test_loopback_check():
    assert all(map(is_loopback, ["127.0.0.1", "localhost", "::1", "[::1]", "127.0.0.2"]))
    assert not any(map(is_loopback, ["0.0.0.0", "192.168.1.4", "example.com", ""]))


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a shell's background command starts


@pytest.mark.parametrize(
    ("stop", "sigint_ignored"),
    [(signal.SIGINT, False), (signal.SIGINT, True), (signal.SIGTERM, False)],
    ids=["sigint", "sigint-started-ignored", "sigterm"],
)
def test_command_serves_until_interrupted(tiny_run, tmp_path, stop, sigint_ignored):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    work = tmp_path / "work"
    command = [sys.executable, "-m", "t2m.serve", "--checkpoints", str(tiny_run), "--port", "0"]
    process = subprocess.Popen(
        command + ["--work-dir", str(work)],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=_ignore_sigint if sigint_ignored else None,
    )
    try:
        url = None
        deadline = time.monotonic() + 90
        while url is None and time.monotonic() < deadline:
            line = process.stderr.readline()
            found = re.search(r"on (http://127\.0\.0\.1:\d+/)", line)
            url = found and found[1]
            assert line or process.poll() is None, "the server ended before serving"
        assert url, "no 'serving ... on URL' line"
        port = int(url.rsplit(":", 1)[1].strip("/"))
        connection = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
        body = json.dumps({"prompts": ["a person walks#40"]})
        connection.request("POST", "/api/generate", body, {"Content-Type": "application/json"})
        assert connection.getresponse().status == 200
        assert len(list(work.iterdir())) == 1
    finally:
        process.send_signal(stop)
        assert process.wait(timeout=30) == 0
        process.stderr.close()
    assert list(work.iterdir()) == []  # the generated files went with the server


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--port", "70000"], "--port must be from 0 to 65535"),
        (["--keep-minutes", "0"], "--keep-minutes must be positive"),
        (["--checkpoints", "/nonexistent/run"], "no checkpoint folder"),
        (["--live-streams", "-1"], "--live-streams must be from 0 to 256"),
    ],
)
def test_command_refuses_bad_options_in_one_line(argv, words, capsys):
    from t2m.serve.__main__ import main

    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err


def test_live_streams_option_reaches_the_server(monkeypatch):
    """``--live-streams N`` is the live hub's cap; 0 turns live mode off with a sentence."""
    from types import SimpleNamespace

    from t2m.serve import live
    from t2m.serve.__main__ import ServeConfig

    assert ServeConfig().live_streams == 8
    assert ServeConfig(live_streams=0).live_streams == 0
    hub = live.LiveHub(SimpleNamespace(precision="fp32"), max_streams=0)
    with pytest.raises(api.Busy, match="live mode is off"):
        hub.open({"text": "a person walks"}, api.Limits())


def test_limits_are_consistent():
    limits = api.Limits()
    assert limits.max_prompts * limits.max_samples >= limits.max_motions
    assert math.log2(limits.max_seed + 1) == 31


@pytest.mark.parametrize("precision", ["bf16", "int8"])
def test_reduced_precisions_are_served(server, precision):
    body = {"prompts": ["a person walks forward#40"], "seed": 1, "precision": precision}
    status, answer, _ = call(server, "POST", "/api/generate", body)
    assert status == 200, answer
    assert answer["precision"] == precision
    assert np.isfinite(np.asarray(answer["motions"][0]["joints"])).all()


def test_an_idle_connection_is_closed(server, monkeypatch):
    import socket

    monkeypatch.setattr(server.RequestHandlerClass, "timeout", 0.5)
    with socket.create_connection(server.server_address[:2], timeout=10) as connection:
        connection.sendall(b"POST /api/generate HTTP/1.1\r\nContent-Length: 100\r\n")
        started = time.monotonic()
        assert connection.recv(1024) == b""  # closed by the server, not by this test's timeout
        assert time.monotonic() - started < 5


def test_served_motions_get_the_clean_up_that_sample_gives(pipe, monkeypatch):
    import t2m.pipeline

    def lifted(features, clean=True):  # a visible stand-in for the finishing step: cleaned,
        features = np.array(features, dtype=np.float32)  # the root joint is 10 cm higher
        if clean:
            features[:, 3] += 0.1
        return features

    monkeypatch.setattr(t2m.pipeline, "finish_features", lifted)
    job = GenerationJob(["a person walks forward"], [40], 1, seed=5, precision="fp32")
    generate_jobs(pipe, [job])
    served = job.result[0][0][0].joints
    cleaned = pipe.generate("a person walks forward", 1, 40, seed=5)[0][0].joints
    raw = pipe.generate("a person walks forward", 1, 40, seed=5, clean=False)[0][0].joints
    np.testing.assert_allclose(served, cleaned, atol=2e-4)
    np.testing.assert_allclose(served[:, 0, 1] - raw[:, 0, 1], 0.1, atol=2e-4)
