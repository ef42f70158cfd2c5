// The page's edit panel: a source motion (uploaded, or one in the view), a mode and its options,
// a timeline of what is kept (green) and generated (grey), and POST /api/edit.
//
// setUpEditPanel(edit, page) wires the panel; `edit` is /api/info's "edit" part, `page` what the
// panel needs from the rest of the page: info (/api/info), current() (the answer in the view or
// null), settings() (the Generate form's samples, seed and precision) and run(makeBody) (send
// the edit and show its answer as the page shows any).

import { $ } from "./dom.js";

const HELP = {
  continue: "keeps the source's start and makes the rest from the text",
  inbetween: "keeps the source's start and end and makes the middle",
  body: "keeps one part of the body on every frame and redoes the rest",
  path: "a new motion whose root passes through the points at their times",
  keys: "a new motion meeting joint targets from a .npy",
  compose: "one motion following several prompts in turn, after a source motion if one is chosen",
};
const MADE_SHADES = ["#d8d8d8", "#c4c4c4"];
const PART_SHADE = "#9fd29f";
const MARK_SHADE = "#b3261e";

function number(id) {
  const value = $(id).value.trim();
  return value === "" ? null : Number(value);
}

function pathRows() {
  return $("edit-path").value.split("\n").filter((l) => l.trim())
    .map((l) => l.trim().split(/[,;\s]+/).map(Number));
}

// The compose timeline's lines as [start, end, "made", text] spans (seconds), after `kept`
// seconds of a source (a "kept" span; 0 without one), where the lines begin.
function composeSpans(kept) {
  let cursor = kept;
  const list = kept > 0 ? [[0, kept, "kept"]] : [];
  for (const line of $("edit-timeline-text").value.split("\n").filter((l) => l.trim())) {
    const parts = line.split("#");
    const start = parts.length === 3 ? Number(parts[1]) : cursor;
    const end = parts.length === 3 ? Number(parts[2]) : cursor + Number(parts[1]);
    if (!(end > start)) continue;
    list.push([start, end, "made", parts[0].trim()]);
    cursor = end;
  }
  return { length: Math.max(cursor, 1), spans: list };
}

// Seconds of the source that start a composed motion: none without a source, else the
// "keep its last" field (empty: the whole source, when its length is known).
function composeKept(sourceSeconds) {
  if ($("edit-source-kind").value === "none") return 0;
  const last = number("edit-keep-last");
  if (last !== null) return sourceSeconds ? Math.min(last, sourceSeconds) : last;
  return sourceSeconds || 0;
}

// The result's timeline for a mode: its length in seconds and [start, end, kind] spans, kind
// "kept" (from the source), "made" (from the text) or "part" (a body part kept on every frame);
// the path mode adds its points' times as marks.
function timeline(mode, sourceSeconds, maxSeconds) {
  const length = Math.min(number("edit-seconds") || sourceSeconds || maxSeconds, maxSeconds);
  if (mode === "continue") {
    const keep = Math.min(number("edit-keep-seconds") || 0, length);
    return { length, spans: [[0, keep, "kept"], [keep, length, "made"]] };
  }
  if (mode === "inbetween") {
    const a = Math.min(number("edit-keep-start") || 0, length);
    const b = Math.min(number("edit-keep-end") || 0, length - a);
    return { length, spans: [[0, a, "kept"], [a, length - b, "made"], [length - b, length, "kept"]] };
  }
  if (mode === "body") {
    const whole = sourceSeconds || maxSeconds;
    return { length: whole, spans: [[0, whole, "part"]] };
  }
  if (mode === "path") {
    const rows = pathRows();
    const last = rows.length ? rows[rows.length - 1][0] : 0;
    const whole = number("edit-seconds") || last || maxSeconds;
    return { length: whole, spans: [[0, whole, "made"]], marks: rows.map((r) => r[0]) };
  }
  if (mode === "compose") return composeSpans(composeKept(sourceSeconds));
  return { length: maxSeconds, spans: [[0, maxSeconds, "made"]] };
}

function drawTimeline(canvas, { length, spans, marks }, keptColor) {
  const c = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height, x = (t) => 4 + ((w - 8) * t) / length;
  c.clearRect(0, 0, w, h);
  c.font = "10px system-ui, sans-serif";
  spans.forEach(([start, end, kind, label], i) => {
    c.fillStyle = kind === "kept" ? keptColor : kind === "part" ? PART_SHADE : MADE_SHADES[i % 2];
    c.fillRect(x(start), 4, Math.max(x(end) - x(start), 1), 16);
    if (label) { c.fillStyle = "#333"; c.fillText(label.slice(0, 24), x(start) + 3, 16); }
  });
  c.fillStyle = "#666";
  for (let t = 0; t <= length + 1e-6; t += length > 12 ? 5 : 1) {
    c.fillRect(x(t), 20, 1, 4);
    c.fillText(`${t}`, x(t) - 3, 33);
  }
  c.fillStyle = MARK_SHADE;
  for (const t of marks || []) c.fillRect(x(t) - 1, 2, 2, 20);
}

// The length of an uploaded file in seconds, read in the page: a BVH's "Frames" and "Frame
// Time" lines, a .npy header's first dimension (at the model's frame rate); null if unknown.
async function uploadSeconds(file, fps) {
  if (!file) return null;
  if (file.name.toLowerCase().endsWith(".bvh")) {
    const head = await file.slice(0, 1 << 20).text();
    const frames = /Frames:\s*(\d+)/.exec(head), time = /Frame Time:\s*([0-9.eE+-]+)/.exec(head);
    return frames && time ? Number(frames[1]) * Number(time[1]) : null;
  }
  const head = await file.slice(0, 1024).text();
  const shape = /'shape':\s*\((\d+)/.exec(head);
  return shape ? Number(shape[1]) / fps : null;
}

// What the panel says of the server's bound on a source (/api/info's limits.max_source_frames:
// frames after resampling to the model's rate), and whether a source of `seconds` (null:
// unknown) exceeds it.
export function sourceLimit(info, seconds) {
  const frames = info.limits.max_source_frames, fps = info.fps;
  const bound = `at most ${frames} frames (${(frames / fps).toFixed(1)} s at ${fps} fps)`;
  const over = seconds !== null && seconds * fps + 1 > frames;
  return {
    note: `A source motion is ${bound} after resampling.`,
    over,
    warning: over ? `This file lasts ${seconds.toFixed(1)} s: the server takes a source of ${bound}; trim it first.` : "",
  };
}

async function base64Of(file) {
  const url = await new Promise((resolve, reject) => {
    const reader = new FileReader();
    reader.onload = () => resolve(reader.result);
    reader.onerror = () => reject(new Error(`cannot read ${file.name}`));
    reader.readAsDataURL(file);
  });
  return url.slice(url.indexOf(",") + 1);
}

async function upload(file) {
  return { upload: { name: file.name, base64: await base64Of(file) } };
}

async function sourceOf(current) {
  if ($("edit-source-kind").value === "current") {
    if (!current) throw new Error("no motion in the view: generate one first, or upload a file");
    return { result: current.id, motion: Number($("edit-current").value) };
  }
  const file = $("edit-file").files[0];
  if (!file) throw new Error("choose a BVH or .npy file to edit");
  return upload(file);
}

// The POST /api/edit body from the panel's fields (t2m/serve/editing.py lists the keys).
async function requestBody(page) {
  const mode = $("edit-mode").value;
  const request = { mode, ...page.settings() };
  if (mode !== "compose") request.text = $("edit-text").value;
  if (["continue", "inbetween", "body"].includes(mode)) request.source = await sourceOf(page.current());
  if (mode === "compose" && $("edit-source-kind").value !== "none") {
    request.source = await sourceOf(page.current());
    const last = number("edit-keep-last");
    if (last !== null) request.keep_last = last;
  }
  if (mode === "continue") request.keep_seconds = number("edit-keep-seconds") ?? 0;
  if (mode === "inbetween") {
    request.keep_start = number("edit-keep-start") ?? 0;
    request.keep_end = number("edit-keep-end") ?? 0;
  }
  if (["continue", "inbetween", "path"].includes(mode)) request.seconds = number("edit-seconds");
  if (mode === "body") request.part = $("edit-part").value;
  if (mode === "path") request.path = pathRows();
  if (mode === "keys") {
    const file = $("edit-keys").files[0];
    if (!file) throw new Error("choose a .npy of joint targets");
    request.keys = await upload(file);
  }
  if (mode === "compose") request.timeline = $("edit-timeline-text").value.split("\n");
  return request;
}

function fillChoices(edit) {
  for (const name of edit.modes) $("edit-mode").add(new Option(name, name));
  for (const name of edit.parts) $("edit-part").add(new Option(name.replace("_", " "), name));
  $("edit-keep-seconds").value = edit.defaults.keep_seconds;
  $("edit-keep-start").value = edit.defaults.keep_start;
  $("edit-keep-end").value = edit.defaults.keep_end;
  $("edit-part").value = edit.defaults.part;
}

// Wire the panel; the answer's refresh(answer) lists the motions of a newly shown answer as
// sources.
export function setUpEditPanel(edit, page) {
  const intro = edit.available
    ? `Pick a motion (uploaded, or one in the view), what to keep and what to change, and describe the change. ${sourceLimit(page.info, null).note}`
    : `Not available: ${edit.reason}.`;
  $("edit-status").textContent = intro;
  $("edit-fields").disabled = !edit.available;
  if (!edit.available) return { refresh() {} };
  fillChoices(edit);
  const fps = page.info.fps, maxSeconds = page.info.max_frames / fps;
  let sourceSeconds = null;  // length of the chosen source, when known

  function draw() {
    const mode = $("edit-mode").value;
    const shown = timeline(mode, sourceSeconds, maxSeconds);
    drawTimeline($("edit-timeline"), shown, edit.highlight_color);
    const part = $("edit-part").value.replace("_", " ");
    const what = mode === "body" ? `the ${part} is kept (green) on every frame` : "green: kept from the source; grey: made from the text";
    $("edit-timeline-note").textContent = `${shown.length.toFixed(1)} s; ${what}`;
  }

  function chooseCurrent() {
    const motions = page.current() ? page.current().motions : [];
    const m = motions[Number($("edit-current").value)];
    sourceSeconds = m ? m.frames / fps : null;
    $("edit-status").textContent = intro;  // the bound is on uploads only
    draw();
  }

  async function chooseUpload(file) {
    sourceSeconds = await uploadSeconds(file, fps);
    const limit = sourceLimit(page.info, sourceSeconds);
    $("edit-status").textContent = limit.over ? limit.warning : intro;
    draw();
  }

  // The source choices of a mode: "none" (a new motion) for compose only, and compose starts
  // from none until a source is chosen.
  let shownMode = null;
  function sourceChoices(mode) {
    const kind = $("edit-source-kind");
    kind.querySelector('option[value="none"]').disabled = mode !== "compose";
    const before = kind.value;
    if (mode === "compose" && shownMode !== "compose") kind.value = "none";
    if (mode !== "compose" && kind.value === "none") kind.value = "upload";
    shownMode = mode;
    if (kind.value !== before) kind.dispatchEvent(new Event("change"));
  }

  function update() {
    const mode = $("edit-mode").value;
    sourceChoices(mode);
    for (const row of document.querySelectorAll("#edit-panel [data-modes]")) {
      row.hidden = !row.dataset.modes.split(" ").includes(mode);
    }
    $("edit-mode-help").textContent = HELP[mode] || "";
    draw();
  }

  function refresh(answer) {
    const select = $("edit-current");
    select.innerHTML = "";
    answer.motions.forEach((m, i) => {
      select.add(new Option(`${i + 1}: ${m.text.slice(0, 40)} (${(m.frames / fps).toFixed(1)} s)`, String(i)));
    });
    if ($("edit-source-kind").value === "current") chooseCurrent();
  }

  $("edit-mode").addEventListener("change", update);
  for (const id of ["edit-keep-seconds", "edit-keep-start", "edit-keep-end", "edit-keep-last", "edit-seconds", "edit-path", "edit-timeline-text", "edit-part"]) {
    $(id).addEventListener("input", draw);
  }
  $("edit-source-kind").addEventListener("change", (e) => {
    const kind = e.target.value;
    $("edit-file").hidden = kind !== "upload";
    $("edit-current").hidden = kind !== "current";
    if (kind === "current") chooseCurrent();
    else if (kind === "upload") chooseUpload($("edit-file").files[0]);
    else draw();
  });
  $("edit-current").addEventListener("change", chooseCurrent);
  $("edit-file").addEventListener("change", (e) => chooseUpload(e.target.files[0]));
  $("edit-run").addEventListener("click", () => page.run(() => requestBody(page)));
  update();
  return { refresh };
}
