// The page's 3D figure viewer: a perspective camera drawn on a 2D canvas, no library.
//
// World: metres, +Y up, a body facing +Z has its left side at +X (the dataset's convention).
// The camera orbits a target point (yaw about +Y, pitch above the floor, distance); each point is
// projected with a pinhole model and the bones are drawn far to near, so nearer limbs cover
// farther ones. Left limbs, right limbs and the spine take the colours of the project's
// renderings; the floor grid and each motion's root trajectory lie at the lowest foot height.
//
// Two ways to draw a figure (the property `figure`): "body" draws each bone as a capsule, a thick
// line with round caps whose width is the limb's radius (BODY_RADII, metres, by the bone's child
// joint) seen at the bone's depth, shaded by a darker outline under a lighter core, with a head
// sphere above the neck and a hand past each wrist; "sticks" draws each bone as a thin line.
//
// The viewer owns its canvas only: the page drives it through the methods and properties below
// (setMotions, show, seek, playing, speed, loop, follow, figure, resetCamera) and hears back
// through onFrame(frame) after every drawn frame and onFirstFrame() once new motions are on screen.

// Limb radii in metres, by the lower-cased name of the joint a bone ends at (SMPL and KIT names);
// other bones take DEFAULT_RADIUS.
const BODY_RADII = {
  // SMPL
  left_hip: 0.075, right_hip: 0.075, left_knee: 0.07, right_knee: 0.07,
  left_ankle: 0.05, right_ankle: 0.05, left_foot: 0.04, right_foot: 0.04,
  spine1: 0.1, spine2: 0.11, spine3: 0.12, neck: 0.09, head: 0.05,
  left_collar: 0.065, right_collar: 0.065, left_shoulder: 0.055, right_shoulder: 0.055,
  left_elbow: 0.045, right_elbow: 0.045, left_wrist: 0.035, right_wrist: 0.035,
  // KIT
  bp: 0.11, bt: 0.12, bln: 0.09, bun: 0.05, ls: 0.06, rs: 0.06, le: 0.045, re: 0.045,
  lw: 0.035, rw: 0.035, lh: 0.075, rh: 0.075, lk: 0.07, rk: 0.07, la: 0.05, ra: 0.05,
  lmrot: 0.04, rmrot: 0.04, lf: 0.035, rf: 0.035,
};
const DEFAULT_RADIUS = 0.045;
const TORSO_INNER = new Set(["spine1", "spine2", "bp"]);  // passed over: one torso capsule
const HEAD_RADIUS = 0.1;      // the head sphere, its centre this far past the head joint:
const HEAD_LIFT = 0.07;       // along the neck-to-head direction
const HAND = [0.07, 0.04];    // a hand past each wrist: length along the forearm, radius
const CENTER_BODY = "#5a5a5a";  // the spine's and head's colour in the body (the sticks' is darker)

export class StickViewer {
  #dirty = true;  // something changed since the last drawn frame
  #playing = true;
  #follow = true;
  #figure = "body";

  constructor(canvas) {
    this.canvas = canvas;
    this.context = canvas.getContext("2d");
    this.motions = [];          // [{joints: Float32Array(T * J * 3), frames, text, offset: [x, z]}]
    this.skeleton = null;       // {parents, chains, sides, colors}
    this.fps = 20;
    this.time = 0;              // seconds into the motions
    this.speed = 1;
    this.loop = true;
    this.visible = -1;          // -1: all side by side; else one motion's index
    this.spacing = 0.6;         // metres between the X ranges of side-by-side motions
    this.floor = 0;
    this.highlightColor = "#2ca02c";
    this.resetCamera();
    this.onFrame = null;        // callback(frame) after every drawn frame
    this.onFirstFrame = null;   // callback() after the first frame of new motions is drawn
    this._last = null;
    this._bindMouse();
    requestAnimationFrame((now) => this._tick(now));
  }

  resetCamera() {
    this.yaw = 0.45;      // radians about +Y; 0 looks at a +Z-facing body from the front
    this.pitch = 0.32;    // radians above the floor
    this.distance = 4.2;  // metres from the target
    this.target = [0, 0.9, 0];
    this.#dirty = true;
  }

  setMotions(motions, fps, skeleton) {
    this.fps = fps;
    this.skeleton = skeleton;
    const jointCount = skeleton.parents.length;
    this.motions = motions.map((m, index) => ({
      joints: Float32Array.from(m.joints.flat()),
      kept: m.kept || null,     // an edit's: per frame a string of '0' / '1' per joint
      frames: m.frames,
      text: m.text,
      index,
    }));
    this.jointCount = jointCount;
    const names = skeleton.joint_names.map((name) => name.toLowerCase());
    this.headJoint = Math.max(names.indexOf("head"), names.indexOf("bun"), 0);  // SMPL, KIT
    this.radii = names.map((name) => BODY_RADII[name] ?? DEFAULT_RADIUS);
    this.torso = names.map((name) => TORSO_INNER.has(name));
    this.wrists = names.flatMap((name, j) => (/(^|_)wrist$|^[lr]w$/.test(name) ? [j] : []));
    let floor = Infinity;
    for (const m of this.motions) {
      for (let i = 1; i < m.joints.length; i += 3) floor = Math.min(floor, m.joints[i]);
    }
    this.floor = Number.isFinite(floor) ? floor : 0;
    this._layOut();
    this.distance = Math.max(4.2, 1.1 * this.rowWidth);
    this.time = 0;
    this._firstPending = true;
    this.#dirty = true;
  }

  // Show every motion side by side (index -1) or one; the camera backs off to fit the row.
  show(index) {
    this.visible = index;
    this.distance = index < 0 ? Math.max(4.2, 1.1 * this.rowWidth) : 4.2;
    this.#dirty = true;
  }

  get playing() {
    return this.#playing;
  }

  set playing(value) {
    this.#playing = value;
    this.#dirty = true;
  }

  // follow: the camera aims at the shown motions' roots as they move
  get follow() {
    return this.#follow;
  }

  set follow(value) {
    this.#follow = value;
    this.#dirty = true;
  }

  // figure: "body" (capsules) or "sticks" (lines)
  get figure() {
    return this.#figure;
  }

  set figure(value) {
    this.#figure = value === "sticks" ? "sticks" : "body";
    this.#dirty = true;
  }

  get frameCount() {
    return this.motions.reduce((most, m) => Math.max(most, m.frames), 0);
  }

  get frame() {
    return Math.min(Math.floor(this.time * this.fps), Math.max(this.frameCount - 1, 0));
  }

  seek(frame) {
    this.time = (frame + 0.5) / this.fps;  // the middle of the frame: no rounding down
    this.#dirty = true;
  }

  _shown() {
    if (this.visible < 0 || this.visible >= this.motions.length) return this.motions;
    return [this.motions[this.visible]];
  }

  // Side by side: each motion is shifted along X so that the X ranges its joints sweep over the
  // whole motion do not overlap (a gap of this.spacing between them), the row centred on 0.
  _layOut() {
    let edge = 0;
    const ranges = this.motions.map((m) => {
      let low = Infinity, high = -Infinity;
      for (let i = 0; i < m.joints.length; i += 3) {
        low = Math.min(low, m.joints[i]);
        high = Math.max(high, m.joints[i]);
      }
      return [low, high];
    });
    this.offsets = ranges.map(([low, high]) => {
      const offset = edge - low;
      edge += high - low + this.spacing;
      return offset;
    });
    this.rowWidth = Math.max(edge - this.spacing, 0);
    this.offsets = this.offsets.map((o) => o - this.rowWidth / 2);
  }

  // Where each shown motion is drawn (one at a time: where it is).
  _offset(motion) {
    return this.visible < 0 ? this.offsets[motion.index] : 0;
  }

  _joint(motion, frame, joint, dx) {
    const f = Math.min(frame, motion.frames - 1);
    const base = (f * this.jointCount + joint) * 3;
    const j = motion.joints;
    return [j[base] + dx, j[base + 1] - this.floor, j[base + 2]];
  }

  _tick(now) {
    if (this._last !== null && this.#playing && this.motions.length) {
      const total = this.frameCount / this.fps;
      this.time += ((now - this._last) / 1000) * this.speed;
      if (this.time >= total) {
        if (this.loop) this.time %= total;
        else { this.time = Math.max(total - 1e-6, 0); this.#playing = false; }
      }
      this.#dirty = true;
    }
    this._last = now;
    if (this.#dirty) {
      this.draw();
      this.#dirty = false;
    }
    requestAnimationFrame((t) => this._tick(t));
  }

  _camera() {
    const shown = this._shown();
    let target = this.target, distance = this.distance;
    if (this.follow && shown.length) {
      // follow: aim at the middle of the roots' box at this frame, far enough to hold it
      const low = [Infinity, Infinity], high = [-Infinity, -Infinity];
      shown.forEach((m) => {
        const root = this._joint(m, this.frame, 0, this._offset(m));
        low[0] = Math.min(low[0], root[0]); high[0] = Math.max(high[0], root[0]);
        low[1] = Math.min(low[1], root[2]); high[1] = Math.max(high[1], root[2]);
      });
      target = [(low[0] + high[0]) / 2, 0.9, (low[1] + high[1]) / 2];
      distance = Math.max(distance, 1.1 * Math.max(high[0] - low[0], high[1] - low[1]) + 3);
    }
    const cp = Math.cos(this.pitch);
    const eye = [
      target[0] + distance * cp * Math.sin(this.yaw),
      target[1] + distance * Math.sin(this.pitch),
      target[2] + distance * cp * Math.cos(this.yaw),
    ];
    const forward = normalize(sub(target, eye));
    const right = normalize(cross(forward, [0, 1, 0]));
    const up = cross(right, forward);
    const focal = 0.5 * this.canvas.height / Math.tan((40 * Math.PI) / 360);  // 40 degree view
    return { eye, forward, right, up, focal, target };
  }

  _project(camera, point) {
    const d = sub(point, camera.eye);
    const depth = dot(d, camera.forward);
    if (depth < 0.05) return null;
    return [
      this.canvas.width / 2 + (camera.focal * dot(d, camera.right)) / depth,
      this.canvas.height / 2 - (camera.focal * dot(d, camera.up)) / depth,
      depth,
    ];
  }

  _line(camera, a, b, color, width) {
    const p = this._project(camera, a), q = this._project(camera, b);
    if (!p || !q) return;
    const c = this.context;
    c.strokeStyle = color;
    c.lineWidth = width;
    c.beginPath();
    c.moveTo(p[0], p[1]);
    c.lineTo(q[0], q[1]);
    c.stroke();
  }

  draw() {
    const c = this.context, w = this.canvas.width, h = this.canvas.height;
    c.fillStyle = "#fbfbfa";
    c.fillRect(0, 0, w, h);
    const camera = this._camera();
    c.lineCap = "round";
    // 1. floor grid, 0.5 m squares around the target
    const step = 0.5, reach = 4;
    const cx = Math.round(camera.target[0] / step) * step, cz = Math.round(camera.target[2] / step) * step;
    for (let k = -reach / step; k <= reach / step; k++) {
      this._line(camera, [cx + k * step, 0, cz - reach], [cx + k * step, 0, cz + reach], "#d2d2d2", 1);
      this._line(camera, [cx - reach, 0, cz + k * step], [cx + reach, 0, cz + k * step], "#d2d2d2", 1);
    }
    const shown = this._shown();
    const frame = this.frame;
    const bones = [];
    shown.forEach((m) => {
      const dx = this._offset(m);
      // 2. root trajectory on the floor, up to this frame
      c.strokeStyle = "#8a8a8a";
      c.lineWidth = 1.5;
      c.beginPath();
      let started = false;
      for (let f = 0; f <= Math.min(frame, m.frames - 1); f++) {
        const root = this._joint(m, f, 0, dx);
        const p = this._project(camera, [root[0], 0, root[2]]);
        if (!p) { started = false; continue; }
        if (started) c.lineTo(p[0], p[1]); else c.moveTo(p[0], p[1]);
        started = true;
      }
      c.stroke();
      // 3. the skeleton's bones, collected for drawing far to near
      this.skeleton.chains.forEach((chain, k) => {
        const color = this.skeleton.colors[this.skeleton.sides[k]];
        const kept = m.kept ? m.kept[Math.min(frame, m.frames - 1)] : null;
        // the body's torso is one capsule: the spine's inner joints are passed over
        const joints = this.#figure === "body" ? chain.filter((j, i) => i === 0 || !this.torso[j]) : chain;
        for (let i = 1; i < joints.length; i++) {
          const [ja, jb] = [joints[i - 1], joints[i]];
          const a = this._project(camera, this._joint(m, frame, ja, dx));
          const b = this._project(camera, this._joint(m, frame, jb, dx));
          if (!a || !b) continue;
          // a bone between two kept joints (from an edit's source) in the highlight colour
          const both = kept && kept[ja] === "1" && kept[jb] === "1";
          const shade = both ? this.highlightColor : color;
          const depth = (a[2] + b[2]) / 2;
          bones.push({ a, b, ja, jb, color: shade, radius: this.radii[jb], depth, figure: m.index });
        }
      });
      if (this.#figure === "body") this._extremities(camera, m, frame, dx, bones);
    });
    bones.sort((p, q) => q.depth - p.depth);
    if (this.#figure === "body") this._drawBody(camera, bones);
    else this._drawSticks(camera, bones);
    // 4. each motion's number (as in the captions) above its head
    c.fillStyle = "#555";
    c.font = "14px system-ui, sans-serif";
    c.textAlign = "center";
    shown.forEach((m) => {
      const head = this._joint(m, frame, this.headJoint, this._offset(m));
      const p = this._project(camera, [head[0], head[1] + 0.25, head[2]]);
      if (p) c.fillText(String(m.index + 1), p[0], p[1]);
    });
    if (this.onFrame) this.onFrame(frame);
    if (this._firstPending && this.motions.length) {
      this._firstPending = false;
      if (this.onFirstFrame) this.onFirstFrame();
    }
  }

  _drawSticks(camera, bones) {
    const c = this.context;
    for (const bone of bones) {
      c.strokeStyle = bone.color;
      c.lineWidth = Math.max(2, Math.min(9, (camera.focal * 0.045) / bone.depth));
      c.beginPath();
      c.moveTo(bone.a[0], bone.a[1]);
      c.lineTo(bone.b[0], bone.b[1]);
      c.stroke();
    }
  }

  // The head sphere (a ball: a = b) and a hand past each wrist, added to a motion's bones.
  _extremities(camera, m, frame, dx, bones) {
    const parents = this.skeleton.parents;
    const colorOf = (joint) => {
      const k = this.skeleton.chains.findIndex((chain) => chain.slice(1).includes(joint));
      return this.skeleton.colors[this.skeleton.sides[Math.max(k, 0)]];
    };
    const head = this.headJoint, neck = parents[head];
    if (neck >= 0) {
      const h = this._joint(m, frame, head, dx), n = this._joint(m, frame, neck, dx);
      const up = normalize(sub(h, n));
      const p = this._project(camera, [0, 1, 2].map((i) => h[i] + HEAD_LIFT * up[i]));
      if (p) bones.push({ a: p, b: p, color: colorOf(head), radius: HEAD_RADIUS, depth: p[2], figure: m.index });
    }
    for (const wrist of this.wrists) {
      const elbow = parents[wrist];
      if (elbow < 0) continue;
      const w = this._joint(m, frame, wrist, dx), e = this._joint(m, frame, elbow, dx);
      const along = normalize(sub(w, e));
      const a = this._project(camera, w);
      const b = this._project(camera, [0, 1, 2].map((i) => w[i] + HAND[0] * along[i]));
      if (!a || !b) continue;
      const depth = (a[2] + b[2]) / 2;
      bones.push({ a, b, ja: wrist, jb: -1, color: colorOf(wrist), radius: HAND[1], depth, figure: m.index });
    }
  }

  // Capsules far to near, each a darker outline, the limb's colour and a lighter core line. Where
  // a bone meets one drawn before it (a farther bone of the same figure), its outline and colour
  // stop short of the joint (the farther bone's round end fills it), so a limb reads as one piece
  // rather than beads; a ball (a = b, the head) is a disc with a lighter spot to the upper left.
  _drawBody(camera, bones) {
    const c = this.context;
    const drawn = new Set();  // "figure:joint" of the bones drawn so far
    for (const bone of bones) {
      const width = Math.max(3, (2 * camera.focal * bone.radius) / bone.depth);
      const color = bone.color === this.skeleton.colors.center ? CENTER_BODY : bone.color;
      const [dark, light] = shades(color);
      if (bone.a === bone.b) {
        const [x, y] = bone.a, r = width / 2;
        c.fillStyle = dark;
        c.beginPath(); c.arc(x, y, r + 1.5, 0, 2 * Math.PI); c.fill();
        c.fillStyle = color;
        c.beginPath(); c.arc(x, y, r, 0, 2 * Math.PI); c.fill();
        c.fillStyle = light;
        c.beginPath(); c.arc(x - 0.35 * r, y - 0.35 * r, 0.3 * r, 0, 2 * Math.PI); c.fill();
        continue;
      }
      const ends = [bone.ja, bone.jb].map((j) => drawn.has(`${bone.figure}:${j}`));
      const [a, b] = [bone.a, bone.b];
      const length = Math.hypot(b[0] - a[0], b[1] - a[1]) || 1;
      const unit = [(b[0] - a[0]) / length, (b[1] - a[1]) / length];
      for (const [paint, w, cut] of [[dark, width + 3, width + 3], [color, width, width], [light, 0.3 * width, width]]) {
        // at a cut end the stroke stops cut / 2 before the joint (the outline's and the colour's
        // round caps end at the joint; the core stays inside its own bone)
        const [cutA, cutB] = ends.map((end) => (end ? cut / 2 : 0));
        if (cutA + cutB >= length && (cutA === 0) === (cutB === 0)) continue;  // covered
        const from = cutA + cutB >= length ? (cutA ? length : 0) : cutA;
        const to = cutA + cutB >= length ? from : length - cutB;
        c.strokeStyle = paint;
        c.lineWidth = w;
        c.beginPath();
        c.moveTo(a[0] + unit[0] * from, a[1] + unit[1] * from);
        c.lineTo(a[0] + unit[0] * to, a[1] + unit[1] * to);
        c.stroke();
      }
      drawn.add(`${bone.figure}:${bone.ja}`).add(`${bone.figure}:${bone.jb}`);
    }
  }

  _bindMouse() {
    let dragging = null;
    this.canvas.addEventListener("pointerdown", (e) => {
      dragging = [e.clientX, e.clientY];
      this.canvas.setPointerCapture(e.pointerId);
    });
    this.canvas.addEventListener("pointermove", (e) => {
      if (!dragging) return;
      this.yaw -= (e.clientX - dragging[0]) * 0.008;
      this.pitch = Math.max(0.02, Math.min(1.45, this.pitch + (e.clientY - dragging[1]) * 0.006));
      dragging = [e.clientX, e.clientY];
      this.#dirty = true;
    });
    this.canvas.addEventListener("pointerup", () => { dragging = null; });
    this.canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      this.distance = Math.max(1.2, Math.min(20, this.distance * Math.exp(e.deltaY * 0.001)));
      this.#dirty = true;
    }, { passive: false });
  }
}

function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
function cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}
function normalize(a) {
  const n = Math.hypot(a[0], a[1], a[2]) || 1;
  return [a[0] / n, a[1] / n, a[2] / n];
}

// A colour's darker and lighter shades (mixed with black and with white), cached by colour.
const SHADES = new Map();
function shades(color) {
  if (!SHADES.has(color)) {
    if (!/^#[0-9a-f]{6}$/i.test(color)) return [color, color];  // not #rrggbb: unshaded
    const n = parseInt(color.slice(1), 16);
    const rgb = [(n >> 16) & 255, (n >> 8) & 255, n & 255];
    const mix = (t, to) => `rgb(${rgb.map((v) => Math.round(v + (to - v) * t)).join(",")})`;
    SHADES.set(color, [mix(0.4, 0), mix(0.45, 255)]);
  }
  return SHADES.get(color);
}
