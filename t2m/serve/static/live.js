// Live mode: the figure keeps moving and Enter in the prompt box changes what it does.
//
// The server makes the frames (t2m/serve/live.py) and sends them as server-sent events, a
// snippet of 4 frames at a time, a little ahead of the page's clock. The page plays frame f at
// f / fps seconds after the first arrived, holding the last frame when none has come. A prompt
// carries the frame shown when Enter was pressed; the server answers with the frame it takes
// over at and sends that frame and the next ones again: the page drops what it held from there.
//
// Timings: every prompt change leaves a User Timing measure "t2m:live prompt to first frame"
// from the key press to the drawing of the first frame of the new prompt (its detail: the
// boundary frame and the text), which the performance tools show and the status line reads.

import { postJson } from "./api.js";
import { $ } from "./dom.js";

const TRAIL_FRAMES = 100;  // the root's path drawn behind the figure (5 s at 20 fps)

export function setUpLive(viewer, info) {
  const live = {
    session: null, source: null, fps: info.fps, frames: new Map(), last: -1, t0: null,
    shown: -1, pending: null, previousOnFrame: null, latencies: [],
  };

  function status(text) { $("live-status").textContent = text; }

  function showError(message) {
    const box = $("live-error");
    box.textContent = message || "";
    box.hidden = !message;
  }

  function clockFrame() {
    if (live.t0 === null) return 0;
    return Math.floor(((performance.now() - live.t0) / 1000) * live.fps);
  }

  function onSnippet(data) {
    if (data.start <= live.last) {  // a prompt took over earlier: drop what followed
      for (let f = data.start; f <= live.last; f++) live.frames.delete(f);
      live.last = data.start - 1;
    }
    data.joints.forEach((row, i) => {
      live.frames.set(data.start + i, { joints: row, prompt: data.prompt, text: data.text });
    });
    live.last = Math.max(live.last, data.start + data.joints.length - 1);
    if (live.t0 === null) {
      live.t0 = performance.now();
      viewer.setMotions([{ joints: [data.joints[0]], frames: 1, text: data.text }], live.fps, info.skeleton);
      viewer.show(0);
      viewer.playing = false;
      viewer.loop = false;
    }
  }

  // Put the frames up to the clock's into the viewer: the shown one last, its trail before it.
  function tick() {
    if (!live.session) return;
    requestAnimationFrame(tick);
    if (live.t0 === null || live.last < 0) return;
    const frame = Math.min(clockFrame(), live.last);
    const first = Math.max(frame - TRAIL_FRAMES, 0);
    for (const key of live.frames.keys()) {  // forget what is behind the trail
      if (key >= first - 20) break;
      live.frames.delete(key);
    }
    const rows = [];
    for (let f = first; f <= frame; f++) {
      const entry = live.frames.get(f);
      if (entry) rows.push(entry.joints);
    }
    if (!rows.length) return;
    const motion = viewer.motions[0];
    motion.joints = Float32Array.from(rows.flat());
    motion.frames = rows.length;
    motion.text = live.frames.get(frame)?.text || motion.text;
    live.shown = frame;
    viewer.seek(rows.length - 1);
  }

  // After the viewer drew: the first frame of a new prompt ends its latency measure.
  function onFrame() {
    const entry = live.frames.get(live.shown);
    $("clock").textContent = `${(live.shown / live.fps).toFixed(2)} s`;
    if (entry) $("captions").textContent = entry.text;
    const pending = live.pending;
    if (pending && pending.prompt !== null && live.shown >= pending.boundary &&
        entry && entry.prompt === pending.prompt) {
      live.pending = null;
      const end = performance.now();
      const measure = performance.measure("t2m:live prompt to first frame", {
        start: pending.pressed, end, detail: { boundary: pending.boundary, text: pending.text },
      });
      live.latencies.push(measure.duration);
      status(`live: "${pending.text}" from ${(pending.boundary / live.fps).toFixed(1)} s, ` +
        `${Math.round(measure.duration)} ms after Enter`);
    }
  }

  function showLinks(files) {
    const box = $("live-downloads");
    box.innerHTML = "Download the live motion so far: ";
    const names = { "timeline.txt": "timeline (compose)", "motion.npy": "joints .npy",
      "motion.bvh": "BVH", "motion.glb": "glTF .glb" };
    for (const [name, url] of Object.entries(files)) {
      const link = document.createElement("a");
      link.href = url;
      link.textContent = names[name] || name;
      link.setAttribute("download", "");
      link.dataset.kind = name;
      box.append(link, " ");
    }
    box.hidden = false;
  }

  function remember(text, seconds) {
    const list = $("live-history");
    const item = document.createElement("li");
    item.textContent = `${seconds.toFixed(1)} s: ${text}`;
    list.prepend(item);
  }

  async function start(text) {
    showError("");
    stop();
    status("starting…");
    let session;
    try {
      session = await postJson("/api/live", { text, seed: Number($("live-seed").value) });
    } catch (error) {
      showError(error.message);
      status("");
      return;
    }
    Object.assign(live, { session, frames: new Map(), last: -1, t0: null, shown: -1, pending: null });
    live.fps = session.fps;
    live.previousOnFrame = viewer.onFrame;
    viewer.onFrame = onFrame;
    $("live-history").innerHTML = "";
    remember(session.text, 0);
    showLinks(session.files);
    $("live-stop").disabled = false;
    $("live-start").textContent = "Restart";
    const source = new EventSource(session.events);
    live.source = source;
    source.addEventListener("snippet", (event) => onSnippet(JSON.parse(event.data)));
    source.addEventListener("hello", () => status(`live: "${session.text}"`));
    source.addEventListener("failure", (event) => {  // the server's sentence, then the end
      showError(JSON.parse(event.data).error);
      stop();
    });
    source.onerror = () => {
      if (live.source !== source) return;
      showError("the live stream ended (the server stopped or the connection dropped); Start begins a new one");
      stop();
    };
    requestAnimationFrame(tick);
  }

  async function prompt(text, pressed) {
    if (!live.session) return start(text);
    showError("");
    const session = live.session;
    live.pending = { text, pressed, boundary: Infinity, prompt: null };
    const pending = live.pending;
    try {
      const answer = await postJson(session.prompt, { text, frame: live.shown });
      if (live.pending === pending) Object.assign(pending, { boundary: answer.boundary, prompt: answer.prompt });
      remember(answer.text, answer.seconds);
    } catch (error) {
      if (live.pending === pending) live.pending = null;
      showError(error.message);
    }
  }

  function stop() {
    if (live.source) live.source.close();
    if (live.session) {
      navigator.sendBeacon(live.session.close);
      viewer.onFrame = live.previousOnFrame;
      status("stopped");
    }
    live.source = null;
    live.session = null;
    $("live-stop").disabled = true;
    $("live-start").textContent = "Start";
  }

  $("live-prompt").addEventListener("keydown", (event) => {
    if (event.key !== "Enter") return;
    event.preventDefault();
    const text = $("live-prompt").value.trim();
    if (!text) { showError("type a prompt, then press Enter"); return; }
    prompt(text, event.timeStamp);
  });
  $("live-start").addEventListener("click", () => start($("live-prompt").value.trim()));
  $("live-stop").addEventListener("click", stop);
  window.addEventListener("pagehide", stop);
  return { start, stop, get running() { return live.session !== null; } };
}
