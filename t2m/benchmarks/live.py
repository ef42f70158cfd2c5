"""Live mode, measured: a long stream's drift and speed, the web page's latency from Enter to the
first new frame drawn, and the memory of concurrent streams.

    python -m t2m.benchmarks.live stream  --checkpoints DIR [--minutes 10] [--strip PNG]
    python -m t2m.benchmarks.live browser --checkpoints DIR [--changes 60]
    python -m t2m.benchmarks.live memory  --checkpoints DIR [--streams 10] [--seconds 30]

``stream``: one :class:`t2m.live.LiveStream` pulled as fast as it goes for ``--minutes`` of
motion, the prompt changing every ``--every`` seconds through :data:`PROMPTS`: the real-time
factor (seconds of motion per second of computing), the time from a prompt to its first snippet,
and :func:`t2m.live.drift_report` per minute; ``--strip`` writes a key-frame strip of its first
half-minute with the prompts. ``browser``: the web app in headless Chromium (Debian's
``chromium`` and ``chromedriver``), Enter pressed ``--changes`` times at random phases of a
snippet; the page's own measures "t2m:live prompt to first frame". ``memory``: a server with
``--streams`` viewers reading their events for ``--seconds``: the process's resident memory
before and after, and whether every stream kept its pace. Each prints one JSON object.

``--contend K`` runs any of them beside K busy loops (:func:`contending`): every process then
gets a share of the cores, as on a slower CPU (on 2 cores, 4 loops made one stream's computing
2.5x slower). With ``ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2`` this stands in for a
slower AVX2-only CPU; the stream's real-time factor says how much slower it ran.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import random
import resource
import statistics
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np

PROMPTS = (
    "a person walks forward",
    "a person jumps",
    "a person turns around",
    "a person waves with the right hand",
    "a person walks backward",
    "stop",
)


def _pipe(args):
    import torch

    from t2m.pipeline import TextToMotion

    if args.threads:
        torch.set_num_threads(args.threads)
    logging.getLogger("t2m.edit").setLevel(logging.WARNING)
    logging.getLogger("t2m.pipeline").setLevel(logging.ERROR)
    pipe = TextToMotion.from_checkpoints(args.checkpoints)
    return pipe if args.precision == "fp32" else pipe.with_precision(args.precision)


def _rss_mb() -> float:
    with open("/proc/self/status") as handle:
        for line in handle:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


@contextlib.contextmanager
def contending(processes: int) -> Iterator[list[subprocess.Popen]]:
    """``processes`` busy loops (Python processes spinning at the default priority) while the
    block runs; they are killed when it ends, however it ends."""
    spinners: list[subprocess.Popen] = []
    try:
        for _ in range(processes):
            spinners.append(
                subprocess.Popen(
                    [sys.executable, "-c", "while True: pass"],
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
        yield spinners
    finally:
        for spinner in spinners:
            spinner.kill()
        for spinner in spinners:
            spinner.wait()


def run_stream(args) -> dict:
    from t2m.live import drift_report

    pipe = _pipe(args)
    fps = pipe.spec.fps
    stream = pipe.stream(PROMPTS[0], seed=args.seed)
    per_prompt = int(args.every * fps) // 4
    total = int(args.minutes * 60 * fps) // 4
    switch, started = [], time.perf_counter()
    for index in range(total):
        if index and index % per_prompt == 0:
            stream.prompt(PROMPTS[(index // per_prompt) % len(PROMPTS)])
            tick = time.perf_counter()
            stream.next_snippet()
            switch.append(time.perf_counter() - tick)
        else:
            stream.next_snippet()
    elapsed = time.perf_counter() - started
    joints = stream.joints()
    result = {
        "minutes": args.minutes,
        "precision": args.precision,
        "real_time_factor": round(len(joints) / fps / elapsed, 1),
        "prompt_to_first_snippet_ms": {
            "median": round(1000 * statistics.median(switch), 1),
            "p95": round(1000 * float(np.percentile(switch, 95)), 1),
            "count": len(switch),
        },
        "drift_per_minute": [
            {k: round(v, 3) for k, v in w.items()} for w in drift_report(joints, fps, 60.0)
        ],
    }
    from t2m.live import SETTLE_TEXT

    still = []  # the root's speed while settled: from 1 s after "stop" to the next prompt
    for index, prompt in enumerate(stream.prompts):
        stop = stream.prompts[index + 1].start if index + 1 < len(stream.prompts) else len(joints)
        if prompt.text == SETTLE_TEXT and stop - prompt.start > fps:
            root = joints[prompt.start + int(fps) : stop, 0, :]
            still.append(np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=-1).mean() * fps)
    if still:
        result["settled_root_speed_mps"] = round(float(np.mean(still)), 3)
    if args.strip:
        from dataset_tools.viz import render_keyframes

        seconds = min(48.0, len(joints) / fps)
        part = joints[: int(seconds * fps)]
        times = [p.start for p in stream.prompts if p.start < len(part)]
        frames = [min(start + int(1.6 * fps), len(part) - 1) for start in times][:6]
        lines = [line for line in stream.timeline() if float(line.split("#")[1]) < seconds][:6]
        caption = " | ".join(
            f"{float(line.split('#')[1]):g} s: {line.split('#')[0]}" for line in lines
        )
        render_keyframes(part, args.strip, caption, frames=frames, fps=fps)
        result["strip"] = str(args.strip)
    return result


def run_browser(args) -> dict:
    import shutil

    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.keys import Keys

    from t2m.serve.server import make_server

    pipe = _pipe(args)
    server = make_server(pipe, str(args.checkpoints), port=0)
    server.start_in_thread()
    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or shutil.which("chromium-browser")
    for argument in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu"):
        options.add_argument(argument)
    driver = webdriver.Chrome(options=options, service=Service(shutil.which("chromedriver")))
    count = "return performance.getEntriesByName('t2m:live prompt to first frame').length"
    rng = random.Random(args.seed)
    try:
        driver.get(server.url)
        _until(driver, "return document.body.dataset.ready === 'true'")
        driver.find_element("css selector", "input[name=mode][value=live]").click()
        driver.find_element("id", "live-start").click()
        _until(
            driver, "return document.getElementById('live-status').textContent.startsWith('live')"
        )
        time.sleep(2.0)
        box = driver.find_element("id", "live-prompt")
        for index in range(args.changes):
            box.clear()
            box.send_keys(PROMPTS[index % (len(PROMPTS) - 1)] + Keys.ENTER)
            _until(driver, f"{count} >= {index + 1}", 10.0)
            time.sleep(rng.uniform(0.4, 1.2))
        latencies = driver.execute_script(
            "return performance.getEntriesByName('t2m:live prompt to first frame')"
            ".map((m) => m.duration)"
        )
    finally:
        driver.quit()
        server.shutdown_app()
    return {
        "precision": args.precision,
        "changes": len(latencies),
        "median_ms": round(statistics.median(latencies), 1),
        "p95_ms": round(float(np.percentile(latencies, 95)), 1),
        "max_ms": round(max(latencies), 1),
        "under_250_ms": sum(1 for x in latencies if x < 250),
    }


def _until(driver, script: str, timeout: float = 30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script if script.startswith("return") else f"return {script}")
        if value:
            return value
        time.sleep(0.02)
    raise TimeoutError(script)


def run_memory(args) -> dict:
    from t2m.serve.server import make_server

    pipe = _pipe(args)
    server = make_server(pipe, str(args.checkpoints), port=0, live_streams=args.streams)
    server.start_in_thread()
    base = server.url.rstrip("/")
    pipe.prepare(["a person walks"])
    before = _rss_mb()
    counts = [0] * args.streams
    stop = threading.Event()

    def viewer(index: int) -> None:
        body = json.dumps({"text": PROMPTS[index % len(PROMPTS)], "seed": index}).encode()
        request = urllib.request.Request(
            base + "/api/live", data=body, headers={"Content-Type": "application/json"}
        )
        with urllib.request.urlopen(request) as response:
            session = json.loads(response.read())
        with urllib.request.urlopen(base + session["events"]) as events:
            for line in events:
                if line.startswith(b"event: snippet"):
                    counts[index] += 1
                if stop.is_set():
                    break

    threads = [threading.Thread(target=viewer, args=(i,), daemon=True) for i in range(args.streams)]
    for thread in threads:
        thread.start()
    time.sleep(args.seconds)
    after = _rss_mb()
    stop.set()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    server.shutdown_app()
    expected = args.seconds * pipe.spec.fps / pipe.spec.snippet_length
    return {
        "streams": args.streams,
        "seconds": args.seconds,
        "precision": args.precision,
        "rss_before_mb": round(before),
        "rss_after_mb": round(after),
        "per_stream_mb": round((after - before) / args.streams, 1),
        "peak_rss_mb": round(peak),
        "snippets_per_stream_min_max": [min(counts), max(counts)],
        "snippets_expected": round(expected),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m t2m.benchmarks.live", description=__doc__)
    parser.add_argument("what", choices=("stream", "browser", "memory"))
    parser.add_argument("--checkpoints", type=Path, default=Path("checkpoints/demo"))
    parser.add_argument("--precision", default="fp32")
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--every", type=float, default=8.0, help="seconds between prompts")
    parser.add_argument("--strip", type=Path, default=None)
    parser.add_argument("--changes", type=int, default=60)
    parser.add_argument("--streams", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument(
        "--contend",
        type=int,
        default=0,
        help="busy-loop processes beside the measurement (a slower CPU's stand-in)",
    )
    args = parser.parse_args(argv)
    if args.contend < 0:
        parser.error(f"--contend must be 0 or more, not {args.contend}")
    run = {"stream": run_stream, "browser": run_browser, "memory": run_memory}[args.what]
    with contending(args.contend):
        result = run(args)
    if args.contend:
        result["contending_processes"] = args.contend
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
