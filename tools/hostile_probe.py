"""Throw the hostile cases of issue 31 at each area and count those that hold.

Areas: ``t2m.edit`` (options, ``--batch``, path, keys, source, timeline and mapping files), the
web server (routes, headers, bodies, uploads), the original release's loader (crafted
vocabularies, tensors, options, statistics) and ``t2m.export``. A probe holds when the input is
refused the way the project promises: a command exits with status 2 (1 for an OS error) and one
``error:`` line, no traceback, holding the probe's words (the file or key it must name), and
writes nothing; the server answers a 4xx (501 for a method it does not serve), never a 500,
with the security headers and the probe's words; the release loader raises a one-line
UsageError naming the spoiled file.
Everything runs in this process on a copy of each input in a temporary folder::

    python tools/hostile_probe.py --checkpoints RUN_DIR   # a trained run (tiny is enough)
    python tools/hostile_probe.py --checkpoints RUN_DIR --area edit -v

The release probes need ``../shared/reference/t2m-original`` (else they are listed as skipped).
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import io
import json
import pickle
import shutil
import socket
import sys
import tempfile
import time
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT.parent / "shared" / "reference" / "t2m-original"
DEEP = "[" * 100_000 + "]" * 100_000
HUGE = "9" * 400

Probe = tuple[str, Callable[[], str | None]]  # (name, check: None when it held, else why not)


def run_command(main, argv: list[str], *words: str, out: Path | None = None) -> str | None:
    """None when ``main(argv)`` refuses in one line holding every word and writes no ``out``."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), warnings.catch_warnings():
        warnings.simplefilter("always")
        try:
            code = main(argv)
        except BaseException as error:  # a probe reports every escape
            return f"raised {type(error).__name__}: {str(error)[:80]}"
    lines = [line for line in err.getvalue().splitlines() if line.startswith("error:")]
    if "Traceback" in err.getvalue():
        return "traceback"
    if code not in (1, 2) or len(lines) != 1:
        return f"exit {code}, {len(lines)} error lines: {err.getvalue()[-160:]!r}"
    missing = [word for word in words if word not in lines[0]]
    if missing:
        return f"{lines[0][:160]!r} lacks {missing}"
    if out is not None and out.exists():
        return f"{out} was written"
    return None


# ----------------------------------------------------------------------------------------- edit


def edit_probes(run: Path, tmp: Path) -> list[Probe]:
    from t2m.edit.__main__ import main

    rng = np.random.default_rng(3)
    walk = tmp / "walk.npy"
    np.save(walk, _walk(101, rng))
    np.save(tmp / "blink.npy", _walk(3, rng))
    np.save(tmp / "flat.npy", np.zeros((20, 21, 3)))
    out = tmp / "edit-out"

    def cli(argv: list[str], *words: str) -> Callable[[], str | None]:
        given = [*argv, "--checkpoints", str(run), "--out", str(out), "--render", "none"]
        return lambda: run_command(main, given, *words, out=out)

    def file(name: str, text: str) -> str:
        (tmp / name).write_text(text)
        return str(tmp / name)

    def batch(entry: dict | str, *words: str) -> Callable[[], str | None]:
        text = entry if isinstance(entry, str) else json.dumps([entry])
        name = f"edits{len(list(tmp.glob('edits*.json')))}.json"  # one file per probe
        return cli(["--batch", file(name, text)], *words)

    cont = ["--mode", "continue", "--text", "a person sits", "--source", str(walk)]
    path = ["--mode", "path", "--text", "a person walks", "--path"]
    source = {"mode": "continue", "text": "a person sits", "source": str(walk)}
    lines = "".join(f"a person walks#{0.2 * i:.1f}#{0.2 * (i + 1):.1f}\n" for i in range(1000))
    bvh = tmp / "walk.bvh"
    return [
        ("--seconds 1e308", cli([*cont, "--seconds", "1e308"], "--seconds")),
        ("--keep-seconds 1e308", cli([*cont, "--keep-seconds", "1e308"], "--keep-seconds")),
        ("--keep-end 1e308", cli([*cont[:1], "inbetween", *cont[2:], "--keep-end", "1e308"])),
        ("timeline end 1e308", cli(["--mode", "compose", "--timeline", "a#0#1e308"], "line 1")),
        ("timeline length 1e308", cli(["--mode", "compose", "--timeline", "a#1e308"])),
        ("path time 1e308", cli([*path, file("late.csv", "0,0,0\n1e308,0.5,0.5\n")], "late.csv")),
        ("path JSON 100,000 deep", cli([*path, file("deep.json", DEEP)], "deep.json", "deep")),
        ("path JSON 400 digits", cli([*path, file("huge.json", f"[[{HUGE},0,0]]")], "400 digits")),
        (
            "path JSON key twice",
            cli([*path, file("two.json", '{"points": [], "points": []}')], "twice"),
        ),  # fmt: skip
        (
            "path times not increasing",
            cli([*path, file("back.csv", "1,0,0.5\n0.5,0,1\n")], "back.csv"),
        ),  # fmt: skip
        (
            "keys of 21 joints",
            cli(
                ["--mode", "keys", "--text", "a person waves", "--keys", str(tmp / "flat.npy")],
                "flat.npy",
            ),
        ),  # fmt: skip
        ("source of 3 frames", cli([*cont[:5], str(tmp / "blink.npy")], "blink.npy")),
        (
            "timeline file with a gap",
            cli(
                ["--mode", "compose", "--timeline", file("gap.txt", "a#0#2\nb#3#4\n")],
                "gap.txt line 2",
            ),
        ),  # fmt: skip
        (
            "timeline of 1,000 lines",
            cli(
                ["--mode", "compose", "--timeline", file("long.txt", lines)], "--max-timeline-lines"
            ),
        ),  # fmt: skip
        (
            "timeline of 900 s",
            cli(
                ["--mode", "compose", "--timeline", "a#0#300", "b#300#900"],
                "--max-timeline-seconds",
            ),
        ),  # fmt: skip
        ("--source-fps 1e-4", cli([*cont, "--source-fps", "1e-4"], "at most 3600 s")),
        ("--source-fps 0", cli([*cont, "--source-fps", "0"], "--source-fps")),
        ("--candidates 1000000", cli([*cont, "--candidates", "1000000"], "--candidates")),
        (
            "a search past memory",
            cli([*cont, "--candidates", "4096", "--num-samples", "100000"], "GiB"),
        ),  # fmt: skip
        (
            "mapping JSON 100,000 deep",
            lambda: _mapping_probe(main, bvh, file("map.json", DEEP), run, out),
        ),  # fmt: skip
        ("batch text 123", batch({**source, "text": 123}, "edits[0].text")),
        ('batch keep_seconds "2"', batch({**source, "keep_seconds": "2"}, "edits[0].keep_seconds")),
        ("batch timeline 5", batch({"mode": "compose", "timeline": 5}, "edits[0].timeline")),
        ("batch seconds 1e308", batch({**source, "seconds": 1e308}, "edits[0]: seconds")),
        (
            "batch keep_seconds past the end",
            batch({**source, "keep_seconds": 30}, "edits[0]: keep_seconds"),
        ),  # fmt: skip
        ("batch source_fps 0", batch({**source, "source_fps": 0}, "edits[0]: source_fps")),
        ("batch 100,000 deep", batch(DEEP, "nested too deep")),
        ("batch 400 digits", batch(f'[{{"mode": "path", "seconds": {HUGE}}}]', "400 digits")),
        ("batch key twice", batch('[{"mode": "path", "mode": "keys"}]', "twice")),
    ]


def _walk(frames: int, rng: np.random.Generator) -> np.ndarray:
    """Joints (T, 22, 3): the template rest pose walking forward at 1 m/s (20 fps)."""
    from dataset_tools.skeleton import SMPL

    pose = np.zeros((22, 3))
    pose[0] = (0.0, 0.95, 0.0)
    for joint, parent in enumerate(SMPL.parents):
        if parent >= 0:
            pose[joint] = pose[parent] + SMPL.offsets[joint]
    steps = np.arange(frames)[:, None] * np.array([0.0, 0.0, 0.05])
    return pose[None] + steps[:, None] + rng.normal(0, 1e-3, (frames, 22, 3))


def _mapping_probe(main, bvh: Path, mapping: str, run: Path, out: Path) -> str | None:
    from dataset_tools.bvh import write_bvh

    write_bvh(_walk(40, np.random.default_rng(1)), bvh)
    argv = ["--mode", "body", "--text", "a person waves", "--source", str(bvh),
            "--mapping", mapping, "--checkpoints", str(run), "--out", str(out), "--render", "none"]  # fmt: skip
    return run_command(main, argv, "map.json", "nested too deep", out=out)


# ---------------------------------------------------------------------------------------- serve


def serve_probes(run: Path, tmp: Path) -> tuple[list[Probe], Callable[[], None]]:
    from t2m.pipeline import TextToMotion
    from t2m.serve.server import make_server

    pipe = TextToMotion.from_checkpoints(run, device="cpu")
    server = make_server(pipe, str(run), port=0, work_dir=tmp / "serve-work")
    server.start_in_thread()
    host, port = server.server_address[:2]

    def send(data: bytes) -> tuple[int, dict, str]:
        with socket.create_connection((host, port), timeout=120) as connection:
            connection.sendall(data)
            connection.shutdown(socket.SHUT_WR)
            answer = b""
            while chunk := connection.recv(65536):
                answer += chunk
        head, _, body = answer.partition(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        headers = dict(line.split(":", 1) for line in lines[1:] if ":" in line)
        headers = {k.strip().lower(): v.strip() for k, v in headers.items()}
        return int(lines[0].split()[1]), headers, body.decode("utf-8", "replace")

    def post(route: str, body: bytes | dict, length: bytes | None = None) -> bytes:
        raw = body if isinstance(body, bytes) else json.dumps(body).encode()
        size = length if length is not None else str(len(raw)).encode()
        return (f"POST {route} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                "Content-Length: ").encode() + size + b"\r\n\r\n" + raw  # fmt: skip

    def refused(data: bytes, *words: str, status: int | None = None) -> Callable[[], str | None]:
        def check() -> str | None:
            code, headers, body = send(data)
            failed = code < 400 or (code >= 500 and code != 501)  # 501: a method not served
            if failed or (status is not None and code != status):
                return f"answered {code}: {body[:120]!r}"
            if (
                "content-security-policy" not in headers
                or headers.get("x-content-type-options") != "nosniff"
            ):
                return "no security headers"
            missing = [word for word in words if word not in body]
            return f"{body[:160]!r} lacks {missing}" if missing else None

        return check

    def timed(check: Callable[[], str | None], seconds: float) -> Callable[[], str | None]:
        def within() -> str | None:
            started = time.perf_counter()
            problem = check()
            took = time.perf_counter() - started
            return problem or (f"took {took:.1f} s" if took > seconds else None)

        return within

    def upload(name: str, content: bytes) -> dict:
        return {"upload": {"name": name, "base64": base64.b64encode(content).decode()}}

    def npy(array: np.ndarray) -> bytes:
        buffer = io.BytesIO()
        np.save(buffer, array)
        return buffer.getvalue()

    from dataset_tools.bvh import write_bvh

    write_bvh(_walk(10, np.random.default_rng(3)), tmp / "w.bvh")
    head, _, frames = (tmp / "w.bvh").read_text().partition("Frame Time:")
    slow = (head + "Frame Time: 100000\n" + frames.split("\n", 1)[1]).encode()
    walk = npy(_walk(61, np.random.default_rng(3)))
    path = {"mode": "path", "text": "a person walks forward"}
    get = b"GET /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\n"
    probes = [
        ("path time 1e308", refused(post("/api/edit", {**path, "path": [[1e308, 1, 1]]}),
                                    "path row 1")),  # fmt: skip
        ("400-digit integer", refused(post("/api/edit", f'{{"mode": "path", "path": [[{HUGE}, 0, 0]]}}'.encode()), "400 digits")),
        ("1e400", refused(post("/api/generate", b'{"prompts": ["a"], "seconds": 1e400}'), "1e400")),
        ("NaN", refused(post("/api/generate", b'{"prompts": ["a"], "seconds": NaN}'), "NaN")),
        ("JSON 100,000 deep", refused(post("/api/edit", DEEP.encode()), "nested too deep")),
        ("JSON key twice", refused(post("/api/generate", b'{"seed": 1, "seed": 2}'), "twice")),
        ("5 MB of escaped quotes", timed(refused(post("/api/edit", b'"' + b'\\"' * 2_500_000), "not valid JSON"), 10)),
        ("malformed JSON", refused(post("/api/generate", b"{not json"), "not valid JSON")),
        ("Content-Length '١٢'", refused(post("/api/generate", b"{}", "١٢".encode()), "Content-Length")),
        ("Content-Length of 5,000 digits", refused(post("/api/generate", b"{}", b"1" * 5000), "at most")),
        ("Host '[::1'", refused(b"GET /api/info HTTP/1.1\r\nHost: [::1\r\n\r\n", status=403)),
        ("two Host headers", refused(get + b"Host: evil.example\r\n\r\n", "Host")),
        ("OPTIONS", refused(b"OPTIONS /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")),
        ("PUT", refused(b"PUT /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 0\r\n\r\n")),
        ("DELETE", refused(b"DELETE /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")),
        ("an invented method", refused(b"BREW /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")),
        ("a malformed request line", refused(b"GET\r\n\r\n")),
        ("BVH of frame time 100000", refused(post("/api/edit", {"mode": "body", "text": "a person waves", "source": upload("slow.bvh", slow)}), "slow.bvh", "1200")),
        ("keep_seconds past the source", refused(post("/api/edit", {"mode": "continue", "text": "a person sits", "keep_seconds": 25, "seconds": 28, "source": upload("walk.npy", walk)}), "keep_seconds 25")),
        ("keys upload of 21 joints", refused(post("/api/edit", {"mode": "keys", "text": "a person waves", "keys": upload("t.npy", npy(np.zeros((20, 21, 3))))}), "the uploaded t.npy")),
        ("source upload of 3 frames", refused(post("/api/edit", {"mode": "body", "text": "a person waves", "source": upload("b.npy", npy(_walk(3, np.random.default_rng(1))))}), "the uploaded b.npy")),
        ("a file name as the source", refused(post("/api/edit", {"mode": "body", "text": "a", "source": "/etc/passwd"}), "source")),
        ("a path outside /static/", refused(b"GET /static/../server.py HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n", status=404)),
    ]  # fmt: skip

    def stop() -> None:
        server.shutdown()
        server.server_close()

    return probes, stop


# -------------------------------------------------------------------------------------- release


def release_probes(tmp: Path) -> list[Probe]:
    import torch

    from dataset_tools.command import UsageError
    from t2m.release import load_release

    generator = Path("checkpoints/t2m/Comp_v6_KLD01")

    def spoiled(relative: str, change: Callable[[Path], None]) -> Callable[[], str | None]:
        def check() -> str | None:
            copy = Path(tempfile.mkdtemp(dir=tmp)) / "release"
            shutil.copytree(REFERENCE, copy, ignore=shutil.ignore_patterns("expected.npz"))
            change(copy / relative)
            try:
                load_release(copy)
            except UsageError as error:
                message = str(error)
                if "\n" in message or str(copy / relative) not in message:
                    return f"{message[:160]!r} does not name {relative}"
                return None
            except BaseException as error:  # a probe reports every escape
                return f"raised {type(error).__name__}: {str(error)[:80]}"
            return "loaded"

        return check

    def pickled(change):
        return lambda path: path.write_bytes(pickle.dumps(change(pickle.loads(path.read_bytes()))))

    def weights(entry: str, key: str, value):
        def change(path: Path) -> None:
            checkpoint = torch.load(path, map_location="cpu", weights_only=True)
            checkpoint[entry][key] = value(checkpoint[entry][key])
            torch.save(checkpoint, path)

        return change

    def array(value):
        return lambda path: np.save(path, value)

    tar = f"{generator}/model/latest.tar"
    mixed = pickled(lambda rows: {w: str(r) if r % 2 else r for w, r in rows.items()})
    return [
        ("vocabulary index of int and str", spoiled("glove/our_vab_idx.pkl", mixed)),
        ("vocabulary index of floats", spoiled("glove/our_vab_idx.pkl", pickled(lambda rows: {w: float(r) for w, r in rows.items()}))),
        ("a pickle that names a global", spoiled("glove/our_vab_words.pkl", lambda p: p.write_bytes(b"cos\nsystem\n(S'true'\ntR."))),
        ("0-d text weights", spoiled(tar, weights("text_enc", "pos_emb.weight", lambda t: torch.tensor(1.0)))),
        ("0-d decoder weights", spoiled(tar, weights("mov_dec", "main.0.weight", lambda t: torch.tensor(1.0)))),
        ("integer weights", spoiled(tar, weights("text_enc", "pos_emb.weight", lambda t: t.long()))),
        ("NaN weights", spoiled(tar, weights("text_enc", "pos_emb.weight", lambda t: t * np.nan))),
        ("opt.txt unit_length x", spoiled(f"{generator}/opt.txt", lambda p: p.write_text(p.read_text().replace("unit_length: 4", "unit_length: x")))),
        ("opt.txt not UTF-8", spoiled(f"{generator}/opt.txt", lambda p: p.write_bytes(b"\xff\xfe x"))),
        ("zero std", spoiled(f"{generator}/meta/std.npy", array(np.zeros(263, np.float32)))),
        ("2-d mean", spoiled(f"{generator}/meta/mean.npy", array(np.zeros((2, 263), np.float32)))),
        ("mean of 200 values", spoiled(f"{generator}/meta/mean.npy", array(np.zeros(200, np.float32)))),
    ]  # fmt: skip


# --------------------------------------------------------------------------------------- export


def export_probes(tmp: Path) -> list[Probe]:
    from t2m.export import main

    walk = _walk(12, np.random.default_rng(1))

    def saved(name: str, joints: np.ndarray) -> str:
        np.save(tmp / name, joints)
        return str(tmp / name)

    def cli(argv: list[str], *words: str, out: str | None = None) -> Callable[[], str | None]:
        return lambda: run_command(main, argv, *words, out=Path(out) if out else None)

    def kept(argv: list[str]) -> str | None:
        target = Path(argv[1])
        target.write_text("mine")
        problem = run_command(main, argv, "--overwrite")
        return problem or (None if target.read_text() == "mine" else "the file was replaced")

    (tmp / "text.npy").write_text("not an array")
    out = str(tmp / "x.bvh")
    return [
        ("an existing output", lambda: kept([saved("w.npy", walk), str(tmp / "mine.bvh")])),
        ("--fps 1e9", cli([saved("w.npy", walk), out, "--fps", "1e9"], "--fps", out=out)),
        (".glb --fps 1e300", cli([saved("w.npy", walk), out[:-4] + ".glb", "--fps", "1e300"], "--fps", out=out[:-4] + ".glb")),
        ("joints x 1e300", cli([saved("far.npy", walk * 1e300), out], "far.npy", out=out)),
        ("all-zero joints", cli([saved("zero.npy", np.zeros((12, 22, 3))), out], "zero.npy", out=out)),
        ("NaN joints", cli([saved("nan.npy", walk * np.nan), out], "nan.npy", out=out)),
        ("21 joints", cli([saved("k.npy", np.zeros((12, 21, 3))), out], "k.npy", out=out)),
        ("features of 1e30", cli([saved("f.npy", np.full((12, 263), 1e30)), out], "f.npy", out=out)),
        ("a text file as input", cli([str(tmp / "text.npy"), out], "text.npy", out=out)),
        ("an unknown output suffix", cli([saved("w.npy", walk), str(tmp / "x.txt")], ".bvh")),
        ("a folder as output", cli([saved("w.npy", walk), str(tmp)], str(tmp))),
        ("a place no file can be made", cli([saved("w.npy", walk), "/proc/x.bvh"], "/proc/x.bvh")),
    ]  # fmt: skip


# ----------------------------------------------------------------------------------------- main


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoints", type=Path, required=True, help="a trained run folder")
    parser.add_argument("--area", choices=("edit", "serve", "release", "export"), nargs="*")
    parser.add_argument("-v", "--verbose", action="store_true", help="list every probe")
    args = parser.parse_args()
    areas = args.area or ["edit", "serve", "release", "export"]
    import logging

    logging.disable(logging.WARNING)  # progress and warnings of the refused runs
    table = []
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        for area in areas:
            stop = None
            try:
                if area == "edit":
                    probes = edit_probes(args.checkpoints, tmp)
                elif area == "serve":
                    probes, stop = serve_probes(args.checkpoints, tmp)
                elif area == "release":
                    probes = release_probes(tmp) if REFERENCE.is_dir() else []
                else:
                    probes = export_probes(tmp)
            except Exception as error:  # the area's set-up broke (checkpoints of another version)
                print(f"{area:8} set-up failed: {type(error).__name__}: {str(error)[:160]}")
                table.append((area, 0, 0))
                continue
            held = 0
            for name, check in probes:
                try:
                    problem = check()
                except Exception:  # the probe itself broke: count it failed
                    problem = "probe error: " + traceback.format_exc().strip().splitlines()[-1]
                held += problem is None
                if args.verbose or problem is not None:
                    print(f"{area:8} {'held' if problem is None else 'FAILED':6} {name}"
                          + (f": {problem}" if problem else ""))  # fmt: skip
            if stop is not None:
                stop()
            table.append((area, len(probes), held))
    print("\n| area | probes | held |\n| --- | ---: | ---: |")
    for area, count, held in table:
        print(f"| {area} | {count} | {held} |" if count else f"| {area} | not run | |")
    return 0 if all(count == held for _, count, held in table) else 1


if __name__ == "__main__":
    sys.exit(main())
