// The page's 3D stick-figure viewer: a perspective camera drawn on a 2D canvas, no library.
//
// World: metres, +Y up, a body facing +Z has its left side at +X (the dataset's convention).
// The camera orbits a target point (yaw about +Y, pitch above the floor, distance); each line is
// projected with a pinhole model and the bones are drawn far to near, so nearer limbs cover
// farther ones. Left limbs, right limbs and the spine take the colours of the project's
// renderings; the floor grid and each motion's root trajectory lie at the lowest foot height.
//
// The viewer owns its canvas only: the page drives it through the methods and properties below
// (setMotions, show, seek, playing, speed, loop, follow, resetCamera) and hears back through
// onFrame(frame) after every drawn frame and onFirstFrame() once new motions are on screen.

export class StickViewer {
  #dirty = true;  // something changed since the last drawn frame
  #playing = true;
  #follow = true;

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
        for (let i = 1; i < chain.length; i++) {
          const a = this._project(camera, this._joint(m, frame, chain[i - 1], dx));
          const b = this._project(camera, this._joint(m, frame, chain[i], dx));
          // a bone between two kept joints (from an edit's source) in the highlight colour
          const both = kept && kept[chain[i - 1]] === "1" && kept[chain[i]] === "1";
          const shade = both ? this.highlightColor : color;
          if (a && b) bones.push({ a, b, color: shade, depth: (a[2] + b[2]) / 2 });
        }
      });
    });
    bones.sort((p, q) => q.depth - p.depth);
    for (const bone of bones) {
      const width = Math.max(2, Math.min(9, (camera.focal * 0.045) / bone.depth));
      c.strokeStyle = bone.color;
      c.lineWidth = width;
      c.beginPath();
      c.moveTo(bone.a[0], bone.a[1]);
      c.lineTo(bone.b[0], bone.b[1]);
      c.stroke();
    }
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
