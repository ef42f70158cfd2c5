// The page: the generate form, the player controls, downloads, history and the edit panel.
// It talks to the server's JSON API only (/api/info, /api/generate, /api/results/<id>).
"use strict";

const $ = (id) => document.getElementById(id);
const state = { info: null, current: null, viewer: null, history: [] };
// Timings of the last generation, for the page's tests: click, answer, first drawn frame (ms).
window.t2mTiming = null;

function showError(message) {
  const box = $("error");
  box.textContent = message || "";
  box.hidden = !message;
}

function showWarnings(lines) {
  const box = $("warnings");
  box.textContent = lines.join(" ");
  box.hidden = lines.length === 0;
}

async function callApi(url, options) {
  let response;
  try {
    response = await fetch(url, options);
  } catch (error) {
    throw new Error("the server cannot be reached (is python -m t2m.serve still running?)");
  }
  let data = null;
  try { data = await response.json(); } catch (error) { data = null; }
  if (!response.ok) {
    throw new Error((data && data.error) || `the server answered ${response.status}`);
  }
  return data;
}

async function loadInfo() {
  const info = await callApi("/api/info");
  state.info = info;
  const seconds = (f) => (f / info.fps).toFixed(1);
  $("model-info").textContent =
    `model: ${info.checkpoints} (${info.dataset}, ${info.fps} fps, ` +
    `${seconds(info.min_frames)}–${seconds(info.max_frames)} s per motion)`;
  $("seconds").min = seconds(info.min_frames);
  $("seconds").max = seconds(info.max_frames);
  $("samples").max = info.limits.max_samples;
  $("seed").max = info.limits.max_seed;
  const precision = $("precision");
  precision.innerHTML = "";
  for (const name of info.precisions) precision.add(new Option(name, name));
  if (!info.automatic_length) {
    $("length-mode").value = "seconds";
    $("length-mode").options[0].disabled = true;
    $("seconds-label").hidden = false;
  }
  setUpEditPanel(info.edit);
  const saved = JSON.parse(sessionStorage.getItem("t2m-history") || "null");
  state.history = saved && saved.boot === info.boot ? saved.items : [];
  renderHistory();
}

function request() {
  const body = {
    prompts: $("prompts").value.split("\n"),
    samples: Number($("samples").value),
    seed: Number($("seed").value),
    precision: $("precision").value,
  };
  if ($("length-mode").value === "seconds") body.seconds = Number($("seconds").value);
  return body;
}

// Send a request whose answer is motions (generate, edit) and show them; the button shows
// progress, errors are shown in words.
async function runRequest(url, makeBody, busyText) {
  const clicked = performance.now();
  showError("");
  showWarnings([]);
  const progress = $("progress");
  const buttons = [$("generate"), $("edit-run")];
  buttons.forEach((b) => { b.dataset.wasDisabled = b.disabled; b.disabled = true; });
  progress.className = "busy";
  progress.textContent = `${busyText}…`;
  const ticker = setInterval(() => {
    progress.textContent = `${busyText}… ${((performance.now() - clicked) / 1000).toFixed(1)} s`;
  }, 100);
  try {
    const body = await makeBody();
    const answer = await callApi(url, {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify(body),
    });
    const answered = performance.now();
    window.t2mTiming = { clicked, answered, firstFrame: null, server: answer.timing };
    state.viewer.onFirstFrame = () => {
      window.t2mTiming.firstFrame = performance.now();
      state.viewer.onFirstFrame = null;
    };
    show(answer);
    remember(answer);
    progress.textContent =
      `${answer.motions.length} motions in ${((answered - clicked) / 1000).toFixed(2)} s`;
  } catch (error) {
    showError(error.message);
    progress.textContent = "";
  } finally {
    clearInterval(ticker);
    progress.className = "";
    buttons.forEach((b) => { b.disabled = b.dataset.wasDisabled === "true"; });
  }
}

function generate(event) {
  event.preventDefault();
  return runRequest("/api/generate", async () => request(), "generating");
}
window.t2mRunRequest = runRequest;
window.t2mFormSettings = () => {
  const body = request();
  return { samples: body.samples, seed: body.seed, precision: body.precision };
};

function show(answer) {
  state.current = answer;
  const info = state.info;
  state.viewer.setMotions(answer.motions, answer.fps, info.skeleton);
  state.viewer.highlightColor = info.edit.highlight_color || "#2ca02c";
  state.viewer.playing = true;
  const unknown = answer.prompts.filter((p) => p.unknown_words.length).map(
    (p) => `"${p.text}": the model was not trained on ${p.unknown_words.join(", ")}.`);
  const dropped = answer.prompts.filter((p) => p.dropped_words.length).map(
    (p) => `"${p.text}": too long, ignoring ${p.dropped_words.join(" ")}.`);
  showWarnings(unknown.concat(dropped));
  // which motions to show
  const layout = $("layout");
  layout.innerHTML = "";
  layout.add(new Option("all side by side", "-1"));
  answer.motions.forEach((m, i) => layout.add(new Option(`${i + 1}: ${m.text.slice(0, 30)}`, String(i))));
  layout.value = "-1";
  state.viewer.show(-1);
  // captions, player, downloads
  const captions = $("captions");
  captions.innerHTML = "";
  answer.motions.forEach((m, i) => {
    const item = document.createElement("span");
    item.className = "caption";
    const label = document.createElement("b");
    label.textContent = `${i + 1}.`;
    item.append(label, ` ${m.text} — ${(m.frames / answer.fps).toFixed(1)} s (${m.frames} frames, sample ${m.sample + 1})`);
    captions.append(item);
  });
  const scrub = $("scrub");
  scrub.max = String(state.viewer.frameCount - 1);
  scrub.disabled = false;
  $("play").disabled = false;
  $("play").textContent = "Pause";
  const list = $("downloads");
  list.innerHTML = "";
  answer.motions.forEach((m, i) => {
    const item = document.createElement("li");
    item.append(`${i + 1}. `);
    for (const [kind, url] of Object.entries(m.files)) {
      const link = document.createElement("a");
      link.href = url;
      link.textContent = kind === "npy" ? "joints .npy" : kind === "glb" ? "glTF .glb" : kind.toUpperCase();
      link.setAttribute("download", "");
      link.dataset.kind = kind;
      item.append(link);
    }
    list.append(item);
  });
  const whole = $("request-files");
  whole.innerHTML = "The whole request: ";
  for (const [name, url] of Object.entries(answer.files)) {
    const link = document.createElement("a");
    link.href = url;
    link.textContent = name;
    link.setAttribute("download", "");
    whole.append(link);
  }
  $("downloads-section").hidden = false;
  renderHistory();
  document.dispatchEvent(new CustomEvent("t2m-shown", { detail: answer }));
}

function remember(answer) {
  state.history.unshift({
    id: answer.id,
    texts: answer.edit ? [`${answer.edit.mode}: ${answer.texts.join(" / ")}`] : answer.texts,
    samples: answer.samples,
    seed: answer.seed,
    time: new Date().toLocaleTimeString(),
  });
  sessionStorage.setItem("t2m-history", JSON.stringify({ boot: state.info.boot, items: state.history }));
  renderHistory();
}

function renderHistory() {
  const list = $("history");
  list.innerHTML = "";
  if (!state.history.length) {
    const empty = document.createElement("li");
    empty.className = "empty";
    empty.textContent = "nothing yet";
    list.append(empty);
    return;
  }
  for (const entry of state.history) {
    const item = document.createElement("li");
    if (state.current && state.current.id === entry.id) item.className = "current";
    const button = document.createElement("button");
    button.type = "button";
    button.textContent = `${entry.time}: ${entry.texts.join(" / ")} (${entry.samples}×, seed ${entry.seed})`;
    button.addEventListener("click", async () => {
      showError("");
      try {
        show(await callApi(`/api/results/${encodeURIComponent(entry.id)}`));
      } catch (error) {
        showError(error.message);
      }
    });
    item.append(button);
    list.append(item);
  }
}

function setUpEditPanel(edit) {
  $("edit-status").textContent = edit.available
    ? "Pick a motion (uploaded, or one in the view), what to keep and what to change, and describe the change."
    : `Not available: ${edit.reason}.`;
  $("edit-fields").disabled = !edit.available;
  if (window.t2mEditPanel && edit.available) window.t2mEditPanel(edit, state);
}

function bindPlayer() {
  const viewer = state.viewer;
  viewer.onFrame = (frame) => {
    $("scrub").value = String(frame);
    $("clock").textContent = `${(frame / viewer.fps).toFixed(2)} s`;
    $("play").textContent = viewer.playing ? "Pause" : "Play";
  };
  $("play").addEventListener("click", () => {
    if (!viewer.playing && viewer.frame >= viewer.frameCount - 1) viewer.seek(0);
    viewer.playing = !viewer.playing;
    viewer._dirty = true;
  });
  $("scrub").addEventListener("input", (e) => {
    viewer.playing = false;
    viewer.seek(Number(e.target.value));
  });
  $("speed").addEventListener("change", (e) => { viewer.speed = Number(e.target.value); });
  $("loop").addEventListener("change", (e) => { viewer.loop = e.target.checked; });
  $("follow").addEventListener("change", (e) => { viewer.follow = e.target.checked; viewer._dirty = true; });
  $("layout").addEventListener("change", (e) => viewer.show(Number(e.target.value)));
  $("reset-camera").addEventListener("click", () => viewer.resetCamera());
  // keys on the view: space plays / pauses, the arrows step one frame
  $("view").addEventListener("keydown", (e) => {
    if (e.key === " ") $("play").click();
    else if (e.key === "ArrowLeft" || e.key === "ArrowRight") {
      viewer.playing = false;
      const step = e.key === "ArrowLeft" ? -1 : 1;
      viewer.seek(Math.max(0, Math.min(viewer.frameCount - 1, viewer.frame + step)));
    } else return;
    e.preventDefault();
  });
}

window.addEventListener("DOMContentLoaded", async () => {
  state.viewer = new StickViewer($("view"));
  window.t2mViewerFrame = () => state.viewer.framesDrawn;  // for the page's tests
  bindPlayer();
  $("generate-form").addEventListener("submit", generate);
  $("length-mode").addEventListener("change", (e) => {
    $("seconds-label").hidden = e.target.value !== "seconds";
  });
  $("new-seed").addEventListener("click", () => {
    $("seed").value = String(Math.floor(Math.random() * 1e6));
  });
  try {
    await loadInfo();
    document.body.dataset.ready = "true";
  } catch (error) {
    showError(error.message);
  }
});
