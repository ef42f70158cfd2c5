// The player row under the view: play / pause, the frame slider and clock, speed, loop, follow,
// which motions to show, the camera reset, and keys on the view (space plays or pauses, the
// arrows step one frame).

import { $ } from "./dom.js";

export function bindPlayer(viewer) {
  viewer.onFrame = (frame) => {
    $("scrub").value = String(frame);
    $("clock").textContent = `${(frame / viewer.fps).toFixed(2)} s`;
    $("play").textContent = viewer.playing ? "Pause" : "Play";
  };
  $("play").addEventListener("click", () => {
    if (!viewer.playing && viewer.frame >= viewer.frameCount - 1) viewer.seek(0);
    viewer.playing = !viewer.playing;
  });
  $("scrub").addEventListener("input", (e) => {
    viewer.playing = false;
    viewer.seek(Number(e.target.value));
  });
  $("speed").addEventListener("change", (e) => { viewer.speed = Number(e.target.value); });
  $("loop").addEventListener("change", (e) => { viewer.loop = e.target.checked; });
  $("follow").addEventListener("change", (e) => { viewer.follow = e.target.checked; });
  $("layout").addEventListener("change", (e) => viewer.show(Number(e.target.value)));
  $("reset-camera").addEventListener("click", () => viewer.resetCamera());
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

// Put an answer's motions (generate or edit) in the view, all side by side, playing.
export function playMotions(viewer, answer, info) {
  viewer.setMotions(answer.motions, answer.fps, info.skeleton);
  viewer.highlightColor = info.edit.highlight_color || "#2ca02c";
  viewer.playing = true;
  const layout = $("layout");
  layout.innerHTML = "";
  layout.add(new Option("all side by side", "-1"));
  answer.motions.forEach((m, i) => layout.add(new Option(`${i + 1}: ${m.text.slice(0, 30)}`, String(i))));
  layout.value = "-1";
  viewer.show(-1);
  const scrub = $("scrub");
  scrub.max = String(viewer.frameCount - 1);
  scrub.disabled = false;
  $("play").disabled = false;
  $("play").textContent = "Pause";
}
