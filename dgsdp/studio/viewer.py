"""The studio's 3D dance viewer: a stick figure drawn in perspective on a 2D canvas, in plain JavaScript.

No library and nothing from the internet: the page gets a small JSON value with two local URLs (the joint
positions and the song); the viewer plays the song in an ``<audio>`` element and draws the frame at the audio's
``currentTime``, so picture and music stay in sync whatever the browser does with the audio clock. Drag to turn
the camera, scroll to zoom; the camera follows the dancer. The frame shown is in ``data-frame`` of the viewer and
in its counter text (the browser tests read them).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dgsdp.motion import SMPL24, Skeleton
from dgsdp.utils.io import atomic_write_text


def write_joints_json(
    path: Path, joints: np.ndarray, fps: float, floor_z: float = 0.0, skeleton: Skeleton = SMPL24
) -> Path:
    """Write joint positions (T, J, 3) of ``skeleton``, z-up metres, as the viewer's JSON (millimetre precision):
    the bones are the skeleton's parents, coloured by side (its joint names' left/right)."""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (skeleton.num_joints, 3):
        raise ValueError(
            f"the viewer needs joints (T, {skeleton.num_joints}, 3) of {skeleton.name}, got {joints.shape}"
        )
    side = ["l" if n.startswith("left") else "r" if n.startswith("right") else "c" for n in skeleton.joint_names]
    data = {
        "fps": float(fps),
        "n_frames": int(joints.shape[0]),
        "n_joints": int(joints.shape[1]),
        "parents": list(skeleton.parents),
        "head": skeleton.joint_names.index("head") if "head" in skeleton.joint_names else -1,
        "side": side,
        "floor_z": float(floor_z),
        # integer millimetres keep the file small and exact to what the viewer needs
        "joints_mm": np.round(joints * 1000).astype(np.int64).reshape(-1).tolist(),
    }
    atomic_write_text(path, json.dumps(data, separators=(",", ":")))
    return path


def viewer_value(motion_url: str, audio_url: str, frames: int, fps: float, label: str = "") -> str:
    """The viewer component's value: what to load (JSON text)."""
    return json.dumps({"motion_url": motion_url, "audio_url": audio_url, "frames": frames, "fps": fps, "label": label})


HTML_TEMPLATE = """
<div class="dgsdp-viewer" data-frame="-1" data-frames="0">
  <canvas class="dv-canvas" width="720" height="440"></canvas>
  <div class="dv-bar">
    <button class="dv-play" type="button" disabled>Play</button>
    <audio class="dv-audio" controls preload="auto"></audio>
    <span class="dv-counter">no dance yet</span>
  </div>
</div>
"""

CSS_TEMPLATE = """
.dgsdp-viewer { display: flex; flex-direction: column; gap: 6px; width: 100%; }
.dv-canvas { width: 100%; max-width: 720px; aspect-ratio: 720 / 440; background: #f4f5f7; border-radius: 8px;
             cursor: grab; touch-action: none; }
.dv-bar { display: flex; align-items: center; gap: 10px; flex-wrap: wrap; }
.dv-audio { height: 36px; flex: 1 1 260px; }
.dv-play { padding: 4px 14px; border-radius: 6px; border: 1px solid #999; background: #fff; cursor: pointer; }
.dv-counter { font-family: ui-monospace, monospace; font-size: 13px; min-width: 16ch; }
"""

JS_ON_LOAD = r"""
const root = element.querySelector('.dgsdp-viewer') || element;
const state = { data: null, joints: null, yaw: -0.5, pitch: 0.28, dist: 4.2, target: null, frame: -1,
                loadId: 0 };
const q = (sel) => element.querySelector(sel);
const COLORS = { l: '#2f6fd6', r: '#d64040', c: '#555b66' };

function project(p, cam, w, h) {
  // camera looks at cam.target from yaw/pitch; z-up world
  const dx = p[0] - cam.target[0], dy = p[1] - cam.target[1], dz = p[2] - cam.target[2];
  const cy = Math.cos(cam.yaw), sy = Math.sin(cam.yaw), cp = Math.cos(cam.pitch), sp = Math.sin(cam.pitch);
  const x = cy * dx + sy * dy;                // right
  const fwd = -sy * dx + cy * dy;             // away from camera (horizontal)
  const y = sp * fwd + cp * dz;               // up on screen (the camera looks down by cam.pitch)
  const depth = cam.dist + cp * fwd - sp * dz;
  const f = 1.25 * h;
  const d = Math.max(depth, 0.2);
  return [w / 2 + f * x / d, h / 2 - f * y / d, depth];
}

function jointAt(frame, j) {
  const n = state.data.n_joints, a = state.joints, i = (frame * n + j) * 3;
  return [a[i] / 1000, a[i + 1] / 1000, a[i + 2] / 1000];
}

function draw(frame) {
  const canvas = q('.dv-canvas');
  if (!canvas) return;
  const ctx = canvas.getContext('2d'), w = canvas.width, h = canvas.height;
  ctx.fillStyle = '#f4f5f7';
  ctx.fillRect(0, 0, w, h);
  if (!state.data) {
    ctx.fillStyle = '#889';
    ctx.font = '16px sans-serif';
    ctx.textAlign = 'center';
    ctx.fillText('Generate a dance to see it here', w / 2, h / 2);
    return;
  }
  const d = state.data, n = d.n_joints;
  const pts = [];
  for (let j = 0; j < n; j++) pts.push(jointAt(frame, j));
  // the camera follows the pelvis over the floor and looks at the middle between the floor and the top joint
  const pelvis = pts[0];
  let top = d.floor_z + 1.6;
  for (const p of pts) top = Math.max(top, p[2]);
  const goal = [pelvis[0], pelvis[1], 0.5 * (d.floor_z + top)];
  if (!state.target) state.target = goal.slice();
  for (let k = 0; k < 3; k++) state.target[k] += 0.15 * (goal[k] - state.target[k]);
  const cam = { target: state.target, yaw: state.yaw, pitch: state.pitch, dist: state.dist };
  // floor grid (0.5 m) around the dancer, at the floor height; lines are cut into pieces so that the parts
  // close to or behind the camera can be left out
  ctx.lineWidth = 1;
  ctx.strokeStyle = '#cfd3da';
  const step = 0.5, half = 2.5, pieces = 10;
  const cx = Math.round(state.target[0] / step) * step, cy = Math.round(state.target[1] / step) * step;
  for (let k = -half; k <= half + 1e-9; k += step) {
    for (const axis of [0, 1]) {
      for (let i = 0; i < pieces; i++) {
        const u0 = -half + (2 * half * i) / pieces, u1 = -half + (2 * half * (i + 1)) / pieces;
        const a = axis ? [cx + u0, cy + k] : [cx + k, cy + u0], b = axis ? [cx + u1, cy + k] : [cx + k, cy + u1];
        const p = project([a[0], a[1], d.floor_z], cam, w, h), r = project([b[0], b[1], d.floor_z], cam, w, h);
        if (p[2] < 1.0 || r[2] < 1.0) continue;
        ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(r[0], r[1]); ctx.stroke();
      }
    }
  }
  // shadow: joints dropped onto the floor
  ctx.fillStyle = 'rgba(60, 60, 80, 0.12)';
  for (const p of pts) {
    const s = project([p[0], p[1], d.floor_z], cam, w, h);
    ctx.beginPath(); ctx.arc(s[0], s[1], 5, 0, 2 * Math.PI); ctx.fill();
  }
  // bones, far ones first
  const screen = pts.map((p) => project(p, cam, w, h));
  const bones = [];
  for (let j = 1; j < n; j++) bones.push([j, d.parents[j], (screen[j][2] + screen[d.parents[j]][2]) / 2]);
  bones.sort((a, b) => b[2] - a[2]);
  ctx.lineCap = 'round';
  for (const [j, p] of bones) {
    ctx.strokeStyle = COLORS[d.side[j]] || COLORS.c;
    ctx.lineWidth = Math.max(2, 0.06 * 1.25 * h / Math.max(screen[j][2], 0.2));
    ctx.beginPath(); ctx.moveTo(screen[p][0], screen[p][1]); ctx.lineTo(screen[j][0], screen[j][1]); ctx.stroke();
  }
  // head (the skeleton's "head" joint; files without the field: SMPL's joint 15)
  const headIndex = d.head === undefined ? Math.min(15, n - 1) : d.head;
  if (headIndex >= 0) {
    const head = screen[headIndex];
    ctx.fillStyle = '#555b66';
    ctx.beginPath(); ctx.arc(head[0], head[1], Math.max(4, 0.1 * 1.25 * h / Math.max(head[2], 0.2)), 0, 2 * Math.PI);
    ctx.fill();
  }
  if (d.label) {
    ctx.fillStyle = '#333';
    ctx.font = '14px sans-serif';
    ctx.textAlign = 'left';
    ctx.fillText(d.label, 12, 22);
  }
}

function tick() {
  if (!element.isConnected) return;  // the component left the page
  const audio = q('.dv-audio');
  if (state.data && audio) {
    const d = state.data;
    const frame = Math.max(0, Math.min(d.n_frames - 1, Math.floor(audio.currentTime * d.fps + 1e-6)));
    if (frame !== state.frame || state.dirty) {
      state.frame = frame;
      state.dirty = false;
      draw(frame);
      root.dataset.frame = String(frame);
      const counter = q('.dv-counter');
      if (counter) counter.textContent = `frame ${frame + 1} / ${d.n_frames}  ${audio.currentTime.toFixed(2)} s`;
    }
    root.dataset.playing = audio.paused ? 'false' : 'true';
    const play = q('.dv-play');
    if (play) play.textContent = audio.paused ? 'Play' : 'Pause';
  } else if (state.dirty) {
    state.dirty = false;
    draw(0);
  }
  requestAnimationFrame(tick);
}

async function load() {
  let value = null;
  try { value = props.value ? JSON.parse(props.value) : null; } catch (e) { value = null; }
  const id = ++state.loadId;
  const audio = q('.dv-audio'), play = q('.dv-play'), counter = q('.dv-counter');
  if (!value || !value.motion_url) {
    state.data = null; state.dirty = true;
    root.dataset.frames = '0';
    if (play) play.disabled = true;
    return;
  }
  if (counter) counter.textContent = 'loading the dance...';
  const response = await fetch(value.motion_url);
  if (!response.ok) { if (counter) counter.textContent = `cannot load the dance (${response.status})`; return; }
  const data = await response.json();
  if (id !== state.loadId) return;  // a newer dance arrived meanwhile
  data.label = value.label || '';
  state.data = data;
  state.joints = Int32Array.from(data.joints_mm);
  state.frame = -1; state.target = null; state.dirty = true;
  root.dataset.frames = String(data.n_frames);
  root.dataset.frame = '-1';
  if (audio) { audio.pause(); audio.src = value.audio_url; audio.currentTime = 0; audio.load(); }
  if (play) play.disabled = false;
}

element.addEventListener('click', (ev) => {
  if (!ev.target.classList || !ev.target.classList.contains('dv-play')) return;
  const audio = q('.dv-audio');
  if (!audio || !state.data) return;
  if (audio.paused) audio.play(); else audio.pause();
});
let drag = null;
element.addEventListener('pointerdown', (ev) => {
  if (!ev.target.classList || !ev.target.classList.contains('dv-canvas')) return;
  drag = [ev.clientX, ev.clientY];
  ev.target.setPointerCapture(ev.pointerId);
});
element.addEventListener('pointermove', (ev) => {
  if (!drag) return;
  state.yaw -= (ev.clientX - drag[0]) * 0.008;
  state.pitch = Math.max(-0.2, Math.min(1.3, state.pitch + (ev.clientY - drag[1]) * 0.006));
  drag = [ev.clientX, ev.clientY];
  state.dirty = true;
});
element.addEventListener('pointerup', () => { drag = null; });
element.addEventListener('wheel', (ev) => {
  if (!ev.target.classList || !ev.target.classList.contains('dv-canvas')) return;
  ev.preventDefault();
  state.dist = Math.max(1.5, Math.min(12, state.dist * (ev.deltaY > 0 ? 1.1 : 1 / 1.1)));
  state.dirty = true;
}, { passive: false });

watch('value', () => { load(); });
state.dirty = true;
load();
requestAnimationFrame(tick);
"""
