"""``python -m t2m.serve.measure --checkpoints DIR``: the web app's two speed numbers.

1. Click to first frame: headless Chromium (selenium, the test extra) opens the page of a server
   on 127.0.0.1, types a prompt, sets the samples, clicks Generate; the page leaves User Timing
   marks at the click, the answer (with the server's timing) and the viewer's first drawn frame
   of the answer (``TIMING``). One warm-up click, then ``--repeats`` clicks (seeds 1, 2, ...);
   the median and the range are reported.
2. Throughput: ``--clients`` threads each send ``--requests`` generate requests (one prompt,
   ``--samples`` motions, automatic length, each its own seed) to a server that batches
   waiting requests (``--batch-motions``) and to one that runs them one at a time
   (``--batch-motions 1``), same models, rounds interleaved; motions per second of wall time.
3. Batching alone, without HTTP and threads: ``--clients`` requests generated as one batch and
   one after another, interleaved, ``3 * --rounds`` times; the median of the per-round ratios.
"""

from __future__ import annotations

import http.client
import json
import logging
import statistics
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from dataset_tools.command import CommandParser, UsageError, command, option, parse_config

logger = logging.getLogger("t2m.serve.measure")
PROMPT = "a person walks forward and then waves with the right hand"
TIMING = """const mark = (name) => performance.getEntriesByName(name, 'mark').at(-1);
const [clicked, answered, first] = ['t2m:request', 't2m:answer', 't2m:first-frame'].map(mark);
return first && {clicked: clicked.startTime, answered: answered.startTime,
                 firstFrame: first.startTime, server: answered.detail};"""
"""the last request's User Timing marks in the page (static/app.js), ms; null until drawn"""


@dataclass
class MeasureConfig:
    """``python -m t2m.serve.measure``."""

    checkpoints: Path = field(default=Path("checkpoints/demo"), metadata=option(metavar="DIR"))
    """run folder (or the original release's folder)"""
    samples: int = 3
    """motions per request"""
    repeats: int = 5
    """timed clicks in the browser"""
    clients: int = 4
    """concurrent clients for the throughput"""
    requests: int = 3
    """requests per client and round"""
    rounds: int = 2
    """interleaved rounds per server"""
    batch_motions: int = 32
    """the batching server's batch limit"""
    threads: int = 0
    """torch CPU threads (0: torch's choice)"""
    out: Path | None = None
    """also write the numbers as JSON here"""
    screenshot: Path | None = None
    """save the page after the last click here (PNG)"""
    screenshot_after: float = 1.2
    """seconds of playing before the screenshot"""


def click_to_first_frame(
    url: str, samples: int, repeats: int, screenshot: Path | None, screenshot_after: float = 1.2
) -> list:
    """Seconds from the Generate click to the first drawn frame, ``repeats`` times."""
    import shutil

    browser, driver_path = shutil.which("chromium"), shutil.which("chromedriver")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        browser = None
    if not (browser and driver_path):
        raise UsageError(
            "the click timing needs Debian's chromium and chromium-driver and the selenium "
            "package (pip install -e '.[test]')"
        )
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for argument in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu"):
        options.add_argument(argument)
    options.add_argument("--window-size=1400,980")
    driver = webdriver.Chrome(options=options, service=Service(driver_path))
    timings = []
    try:
        driver.get(url)
        while driver.execute_script("return document.body.dataset.ready") != "true":
            time.sleep(0.05)
        driver.find_element("id", "prompts").clear()
        driver.find_element("id", "prompts").send_keys(PROMPT)
        driver.find_element("id", "samples").clear()
        driver.find_element("id", "samples").send_keys(str(samples))
        for attempt in range(repeats + 1):  # the first is a warm-up
            seed = driver.find_element("id", "seed")
            seed.clear()
            seed.send_keys(str(attempt))
            driver.execute_script("performance.clearMarks()")
            driver.find_element("id", "generate").click()
            timing = None
            while not timing:
                time.sleep(0.01)
                timing = driver.execute_script(TIMING)
            if attempt:
                timings.append(
                    {
                        "first_frame_s": (timing["firstFrame"] - timing["clicked"]) / 1000,
                        "answer_s": (timing["answered"] - timing["clicked"]) / 1000,
                        "server_s": timing["server"]["total_s"],
                    }
                )
        if screenshot is not None:
            time.sleep(screenshot_after)
            driver.save_screenshot(str(screenshot))
    finally:
        driver.quit()
    return timings


def throughput(url: str, clients: int, requests: int, samples: int, first_seed: int) -> float:
    """Motions per second of ``clients`` threads sending ``requests`` requests each."""
    host, port = url.split("//")[1].strip("/").rsplit(":", 1)
    failures = []

    def client(index: int) -> None:
        connection = http.client.HTTPConnection(host, int(port), timeout=600)
        for number in range(requests):
            seed = first_seed + index * requests + number
            body = json.dumps({"prompts": [PROMPT], "samples": samples, "seed": seed})
            connection.request("POST", "/api/generate", body, {"Content-Type": "application/json"})
            response = connection.getresponse()
            response.read()
            if response.status != 200:
                failures.append(response.status)
        connection.close()

    threads = [threading.Thread(target=client, args=(i,)) for i in range(clients)]
    start = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    elapsed = time.perf_counter() - start
    if failures:
        raise RuntimeError(f"{len(failures)} requests failed: {failures[:3]}")
    return clients * requests * samples / elapsed


def batching_ratio(pipe, clients: int, samples: int, rounds: int) -> dict:
    """Seconds to generate ``clients`` requests of ``samples`` motions (automatic lengths, own
    seeds) as one batch and one after another, interleaved ``rounds`` times; medians."""
    from t2m.serve.worker import GenerationJob, generate_jobs

    def jobs(offset: int) -> list:
        return [
            GenerationJob([PROMPT], [None], samples, offset + i, "fp32") for i in range(clients)
        ]

    batched, alone = [], []
    for number in range(rounds + 1):  # the first round warms up
        start = time.perf_counter()
        generate_jobs(pipe, jobs(100 * number))
        middle = time.perf_counter()
        for job in jobs(100 * number):
            generate_jobs(pipe, [job])
        end = time.perf_counter()
        if number:
            batched.append(middle - start)
            alone.append(end - middle)
    return {
        "one_batch_s": statistics.median(batched),
        "one_at_a_time_s": statistics.median(alone),
        "speedup": statistics.median(a / b for a, b in zip(alone, batched)),
    }


@command
def main(argv: list[str] | None = None) -> int:
    import torch

    from t2m.pipeline import TextToMotion
    from t2m.serve.server import make_server

    parser = CommandParser(prog="python -m t2m.serve.measure", description=__doc__.split("\n")[0])
    config = parse_config(parser, MeasureConfig, argv)
    if config.threads:
        torch.set_num_threads(config.threads)
    pipe = TextToMotion.from_checkpoints(config.checkpoints)
    servers = {
        "batched": make_server(pipe, str(config.checkpoints), port=0, max_batch_motions=32),
        "one at a time": make_server(pipe, str(config.checkpoints), port=0, max_batch_motions=1),
    }
    for server in servers.values():
        server.start_in_thread()
    try:
        timings = click_to_first_frame(
            servers["batched"].url,
            config.samples,
            config.repeats,
            config.screenshot,
            config.screenshot_after,
        )
        first = [t["first_frame_s"] for t in timings]
        logger.info(
            "click -> first frame, %d samples: median %.3f s (%.3f .. %.3f), server part "
            "median %.3f s",
            config.samples,
            statistics.median(first),
            min(first),
            max(first),
            statistics.median(t["server_s"] for t in timings),
        )
        rates: dict[str, list[float]] = {name: [] for name in servers}
        throughput(servers["batched"].url, 1, 1, config.samples, 10**6)  # warm-up
        for round_number in range(config.rounds):
            for name, server in servers.items():
                seed = 1000 * round_number
                rate = throughput(server.url, config.clients, config.requests, config.samples, seed)
                rates[name].append(rate)
                logger.info("round %d, %s: %.2f motions/s", round_number, name, rate)
        summary = {
            "checkpoints": str(config.checkpoints),
            "torch_threads": torch.get_num_threads(),
            "samples": config.samples,
            "click_to_first_frame": timings,
            "clients": config.clients,
            "requests_per_client": config.requests,
            "motions_per_second": rates,
            "batched_speedup": statistics.median(rates["batched"])
            / statistics.median(rates["one at a time"]),
            "batches": list(servers["batched"].app.worker.batches),
        }
        logger.info(
            "throughput with %d clients: batched %.2f, one at a time %.2f motions/s (x%.2f)",
            config.clients,
            statistics.median(rates["batched"]),
            statistics.median(rates["one at a time"]),
            summary["batched_speedup"],
        )
        summary["library_batching"] = batching_ratio(
            pipe, config.clients, config.samples, 3 * config.rounds
        )
        logger.info(
            "generation alone, %d requests of %d motions: one batch %.3f s, one at a time "
            "%.3f s (x%.2f, median of the per-round ratios)",
            config.clients,
            config.samples,
            summary["library_batching"]["one_batch_s"],
            summary["library_batching"]["one_at_a_time_s"],
            summary["library_batching"]["speedup"],
        )
        if config.out:
            config.out.write_text(json.dumps(summary, indent=2) + "\n")
    finally:
        for server in servers.values():
            server.shutdown_app()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
