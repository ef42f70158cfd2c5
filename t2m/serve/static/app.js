// The page's entry module (index.html loads it; it imports the rest): the generate form,
// warnings and errors, downloads, the history of requests, and the wiring of the view
// (viewer.js), its player row (player.js), the edit panel (edit.js) and the live mode
// (live.js), chosen by the mode switch. It talks to the server's JSON API only (/api/info,
// /api/generate, /api/results/<id>, /api/edit; live.js: /api/live).
//
// Timings: every request leaves User Timing marks, "t2m:request" (the click), "t2m:answer"
// (the answer arrived; its detail is the server's own "timing" from the answer) and
// "t2m:first-frame" (its first frame drawn), and the measures
// "t2m:request to answer" and "t2m:request to first frame" (the browser's performance tools
// show them; the progress line reads the first).

import { callApi, postJson } from "./api.js";
import { $ } from "./dom.js";
import { setUpEditPanel } from "./edit.js";
import { setUpLive } from "./live.js";
import { bindPlayer, playMotions } from "./player.js";
import { StickViewer } from "./viewer.js";

const HISTORY_KEY = "t2m-history";
const viewer = new StickViewer($("view"));
// the view's "draw" menu: body (capsules) or sticks, remembered by the browser
const FIGURE_KEY = "t2m-figure";
$("figure").value = localStorage.getItem(FIGURE_KEY) === "sticks" ? "sticks" : "body";
viewer.figure = $("figure").value;
$("figure").addEventListener("change", (e) => {
  viewer.figure = e.target.value;
  localStorage.setItem(FIGURE_KEY, viewer.figure);
});
const state = { info: null, current: null, history: [], editPanel: null, live: null };

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

function formSettings() {
  return {
    samples: Number($("samples").value),
    seed: Number($("seed").value),
    precision: $("precision").value,
  };
}

function generateBody() {
  const body = { prompts: $("prompts").value.split("\n"), ...formSettings() };
  if ($("length-mode").value === "seconds") body.seconds = Number($("seconds").value);
  return body;
}

// The form's limits from /api/info.
function applyInfo(info) {
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
}

async function loadInfo() {
  const info = await callApi("/api/info");
  state.info = info;
  applyInfo(info);
  state.editPanel = setUpEditPanel(info.edit, {
    info,
    current: () => state.current,
    settings: formSettings,
    run: (makeBody) => runRequest("/api/edit", makeBody, "editing"),
  });
  state.live = setUpLive(viewer, info);
  // the history survives a reload of the page, not a restart of the server
  const saved = JSON.parse(sessionStorage.getItem(HISTORY_KEY) || "null");
  state.history = saved && saved.boot === info.boot ? saved.items : [];
  renderHistory();
}

// Send a request whose answer is motions (generate, edit) and show them; the progress line
// counts the seconds, errors are shown in words.
async function runRequest(url, makeBody, busyText) {
  const clicked = performance.mark("t2m:request").startTime;
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
    const answer = await postJson(url, await makeBody());
    performance.mark("t2m:answer", { detail: answer.timing || null });
    const waited = performance.measure("t2m:request to answer", "t2m:request", "t2m:answer");
    viewer.onFirstFrame = () => {
      viewer.onFirstFrame = null;
      performance.mark("t2m:first-frame");
      performance.measure("t2m:request to first frame", "t2m:request", "t2m:first-frame");
    };
    show(answer);
    remember(answer);
    progress.textContent =
      `${answer.motions.length} motions in ${(waited.duration / 1000).toFixed(2)} s`;
  } catch (error) {
    showError(error.message);
    progress.textContent = "";
  } finally {
    clearInterval(ticker);
    progress.className = "";
    buttons.forEach((b) => { b.disabled = b.dataset.wasDisabled === "true"; });
  }
}

function showCaptions(answer) {
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
}

function downloadLink(url, text, kind) {
  const link = document.createElement("a");
  link.href = url;
  link.textContent = text;
  link.setAttribute("download", "");
  if (kind) link.dataset.kind = kind;
  return link;
}

const KIND_NAMES = { npy: "joints .npy", glb: "glTF .glb" };

function showDownloads(answer) {
  const list = $("downloads");
  list.innerHTML = "";
  answer.motions.forEach((m, i) => {
    const item = document.createElement("li");
    item.append(`${i + 1}. `);
    for (const [kind, url] of Object.entries(m.files)) {
      item.append(downloadLink(url, KIND_NAMES[kind] || kind.toUpperCase(), kind));
    }
    list.append(item);
  });
  const whole = $("request-files");
  whole.innerHTML = "The whole request: ";
  for (const [name, url] of Object.entries(answer.files)) whole.append(downloadLink(url, name));
  $("downloads-section").hidden = false;
}

// Show an answer (generate, edit, or one from the history): the view, words the model does not
// know, captions, downloads.
function show(answer) {
  state.current = answer;
  playMotions(viewer, answer, state.info);
  const unknown = answer.prompts.filter((p) => p.unknown_words.length).map(
    (p) => `"${p.text}": the model was not trained on ${p.unknown_words.join(", ")}.`);
  const dropped = answer.prompts.filter((p) => p.dropped_words.length).map(
    (p) => `"${p.text}": too long, ignoring ${p.dropped_words.join(" ")}.`);
  showWarnings(unknown.concat(dropped));
  showCaptions(answer);
  showDownloads(answer);
  renderHistory();
  state.editPanel.refresh(answer);
}

function remember(answer) {
  state.history.unshift({
    id: answer.id,
    texts: answer.edit ? [`${answer.edit.mode}: ${answer.texts.join(" / ")}`] : answer.texts,
    samples: answer.samples,
    seed: answer.seed,
    time: new Date().toLocaleTimeString(),
  });
  sessionStorage.setItem(HISTORY_KEY, JSON.stringify({ boot: state.info.boot, items: state.history }));
  renderHistory();
}

async function showStored(id) {
  showError("");
  try {
    show(await callApi(`/api/results/${encodeURIComponent(id)}`));
  } catch (error) {
    showError(error.message);
  }
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
    button.addEventListener("click", () => showStored(entry.id));
    item.append(button);
    list.append(item);
  }
}

// The mode switch: generate and edit, or live (its panel replaces the others; leaving live
// mode ends its stream, and the view shows the last motions generated again).
function setMode(mode) {
  const liveMode = mode === "live";
  document.querySelectorAll("[data-mode=generate]").forEach((element) => {
    element.hidden = liveMode || (element.id === "downloads-section" && !state.current);
  });
  $("live-panel").hidden = !liveMode;
  $("player").hidden = liveMode;
  if (liveMode) $("live-prompt").focus();
  else if (state.live && state.live.running) {
    state.live.stop();
    if (state.current) show(state.current);
  }
}

bindPlayer(viewer);
document.querySelectorAll("input[name=mode]").forEach((radio) => {
  radio.addEventListener("change", (e) => setMode(e.target.value));
});
$("generate-form").addEventListener("submit", (event) => {
  event.preventDefault();
  return runRequest("/api/generate", async () => generateBody(), "generating");
});
$("length-mode").addEventListener("change", (e) => {
  $("seconds-label").hidden = e.target.value !== "seconds";
});
$("new-seed").addEventListener("click", () => {
  $("seed").value = String(Math.floor(Math.random() * 1e6));
});
try {
  await loadInfo();
  $("generate").disabled = false;
  document.body.dataset.ready = "true";
} catch (error) {
  showError(error.message);
}
