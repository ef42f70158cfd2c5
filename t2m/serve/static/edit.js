// The page's edit panel: a source motion (uploaded, or one in the view), a mode and its options,
// a timeline of what is kept (green) and generated (grey), and POST /api/edit.
"use strict";

const HELP = {
  continue: "keeps the source's start and makes the rest from the text",
  inbetween: "keeps the source's start and end and makes the middle",
  body: "keeps one part of the body on every frame and redoes the rest",
  path: "a new motion whose root passes through the points at their times",
  keys: "a new motion meeting joint targets from a .npy",
  compose: "one motion following several prompts in turn",
};

window.t2mEditPanel = function setUpEdit(edit, state) {
  const $ = (id) => document.getElementById(id);
  const mode = $("edit-mode"), part = $("edit-part");
  for (const name of edit.modes) mode.add(new Option(name, name));
  for (const name of edit.parts) part.add(new Option(name.replace("_", " "), name));
  $("edit-keep-seconds").value = edit.defaults.keep_seconds;
  $("edit-keep-start").value = edit.defaults.keep_start;
  $("edit-keep-end").value = edit.defaults.keep_end;
  part.value = edit.defaults.part;
  let sourceSeconds = null;  // length of the chosen source, when known

  function fps() { return state.info.fps; }
  function maxSeconds() { return state.info.max_frames / fps(); }

  function currentMotions() {
    return state.current ? state.current.motions : [];
  }

  function refreshCurrent() {
    const select = $("edit-current");
    select.innerHTML = "";
    currentMotions().forEach((m, i) => {
      select.add(new Option(`${i + 1}: ${m.text.slice(0, 40)} (${(m.frames / fps()).toFixed(1)} s)`, String(i)));
    });
    if ($("edit-source-kind").value === "current") chooseCurrent();
  }

  function chooseCurrent() {
    const m = currentMotions()[Number($("edit-current").value)];
    sourceSeconds = m ? m.frames / fps() : null;
    draw();
  }

  // The length of an uploaded file, read in the page: a BVH's "Frames" and "Frame Time"
  // lines, a .npy header's first dimension (at the model's frame rate).
  async function readUploadLength(file) {
    sourceSeconds = null;
    if (!file) return draw();
    if (file.name.toLowerCase().endsWith(".bvh")) {
      const head = await file.slice(0, 1 << 20).text();
      const frames = /Frames:\s*(\d+)/.exec(head), time = /Frame Time:\s*([0-9.eE+-]+)/.exec(head);
      if (frames && time) sourceSeconds = Number(frames[1]) * Number(time[1]);
    } else {
      const head = await file.slice(0, 1024).text();
      const shape = /'shape':\s*\((\d+)/.exec(head);
      if (shape) sourceSeconds = Number(shape[1]) / fps();
    }
    draw();
  }

  function number(id) {
    const value = $(id).value.trim();
    return value === "" ? null : Number(value);
  }

  // [start, end, kind] spans in seconds on the result's timeline: kind "kept" or "made".
  function spans() {
    const m = mode.value;
    const length = Math.min(number("edit-seconds") || sourceSeconds || maxSeconds(), maxSeconds());
    if (m === "continue") {
      const keep = Math.min(number("edit-keep-seconds") || 0, length);
      return { length, spans: [[0, keep, "kept"], [keep, length, "made"]] };
    }
    if (m === "inbetween") {
      const a = Math.min(number("edit-keep-start") || 0, length);
      const b = Math.min(number("edit-keep-end") || 0, length - a);
      return { length, spans: [[0, a, "kept"], [a, length - b, "made"], [length - b, length, "kept"]] };
    }
    if (m === "body") {
      const whole = sourceSeconds || maxSeconds();
      return { length: whole, spans: [[0, whole, "part"]] };
    }
    if (m === "path") {
      const rows = $("edit-path").value.split("\n").filter((l) => l.trim()).map((l) => l.split(/[,;\s]+/).map(Number));
      const last = rows.length ? rows[rows.length - 1][0] : 0;
      const whole = number("edit-seconds") || last || maxSeconds();
      return { length: whole, spans: [[0, whole, "made"]], marks: rows.map((r) => r[0]) };
    }
    if (m === "compose") {
      let cursor = 0;
      const list = [];
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
    return { length: maxSeconds(), spans: [[0, maxSeconds(), "made"]] };
  }

  function draw() {
    const canvas = $("edit-timeline"), c = canvas.getContext("2d");
    const { length, spans: list, marks } = spans();
    const w = canvas.width, h = canvas.height, x = (t) => 4 + ((w - 8) * t) / length;
    c.clearRect(0, 0, w, h);
    c.font = "10px system-ui, sans-serif";
    list.forEach(([start, end, kind, label], i) => {
      c.fillStyle = kind === "kept" ? edit.highlight_color : kind === "part" ? "#9fd29f" : (i % 2 ? "#c4c4c4" : "#d8d8d8");
      c.fillRect(x(start), 4, Math.max(x(end) - x(start), 1), 16);
      if (label) { c.fillStyle = "#333"; c.fillText(label.slice(0, 24), x(start) + 3, 16); }
    });
    c.fillStyle = "#666";
    for (let t = 0; t <= length + 1e-6; t += length > 12 ? 5 : 1) {
      c.fillRect(x(t), 20, 1, 4);
      c.fillText(`${t}`, x(t) - 3, 33);
    }
    c.fillStyle = "#b3261e";
    for (const t of marks || []) c.fillRect(x(t) - 1, 2, 2, 20);
    const what = mode.value === "body" ? `the ${part.value.replace("_", " ")} is kept (green) on every frame` : "green: kept from the source; grey: made from the text";
    $("edit-timeline-note").textContent = `${length.toFixed(1)} s; ${what}`;
  }

  function update() {
    const m = mode.value;
    for (const row of document.querySelectorAll("#edit-panel [data-modes]")) {
      row.hidden = !row.dataset.modes.split(" ").includes(m);
    }
    $("edit-mode-help").textContent = HELP[m] || "";
    draw();
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

  async function body() {
    const m = mode.value;
    const request = { mode: m, ...window.t2mFormSettings() };
    if (m !== "compose") request.text = $("edit-text").value;
    if (["continue", "inbetween", "body"].includes(m)) {
      if ($("edit-source-kind").value === "current") {
        if (!state.current) throw new Error("no motion in the view: generate one first, or upload a file");
        request.source = { result: state.current.id, motion: Number($("edit-current").value) };
      } else {
        const file = $("edit-file").files[0];
        if (!file) throw new Error("choose a BVH or .npy file to edit");
        request.source = { upload: { name: file.name, base64: await base64Of(file) } };
      }
    }
    if (m === "continue") request.keep_seconds = number("edit-keep-seconds") ?? 0;
    if (m === "inbetween") {
      request.keep_start = number("edit-keep-start") ?? 0;
      request.keep_end = number("edit-keep-end") ?? 0;
    }
    if (["continue", "inbetween", "path"].includes(m)) request.seconds = number("edit-seconds");
    if (m === "body") request.part = part.value;
    if (m === "path") {
      request.path = $("edit-path").value.split("\n").filter((l) => l.trim())
        .map((l) => l.trim().split(/[,;\s]+/).map(Number));
    }
    if (m === "keys") {
      const file = $("edit-keys").files[0];
      if (!file) throw new Error("choose a .npy of joint targets");
      request.keys = { upload: { name: file.name, base64: await base64Of(file) } };
    }
    if (m === "compose") request.timeline = $("edit-timeline-text").value.split("\n");
    return request;
  }

  mode.addEventListener("change", update);
  for (const id of ["edit-keep-seconds", "edit-keep-start", "edit-keep-end", "edit-seconds", "edit-path", "edit-timeline-text", "edit-part"]) {
    $(id).addEventListener("input", draw);
  }
  $("edit-source-kind").addEventListener("change", (e) => {
    const current = e.target.value === "current";
    $("edit-file").hidden = current;
    $("edit-current").hidden = !current;
    if (current) chooseCurrent(); else readUploadLength($("edit-file").files[0]);
  });
  $("edit-current").addEventListener("change", chooseCurrent);
  $("edit-file").addEventListener("change", (e) => readUploadLength(e.target.files[0]));
  document.addEventListener("t2m-shown", refreshCurrent);
  $("edit-run").addEventListener("click", () => window.t2mRunRequest("/api/edit", body, "editing"));
  update();
};
