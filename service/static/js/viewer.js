// The three.js scene: orbit/zoom/pan, fit-to-view, render on demand, and builders for every artifact layer.
// Loaded lazily (dynamic import) so the rest of the dashboard works where WebGL or three.js is missing.

import * as THREE from "three";
import { OrbitControls } from "three/addons/OrbitControls.js";
import { BASE_COLOR, UNASSIGNED_COLOR, UNREACHED_COLOR, heatColor, patchColor } from "./colors.js";

export class Viewer {
  constructor(container) {
    this.container = container;
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.renderer.setClearColor(0x1b1f24, 1);
    const canvas = this.renderer.domElement;
    canvas.setAttribute("aria-label", "3D view: drag to orbit, wheel or pinch to zoom, right-drag to pan, F to fit");
    canvas.setAttribute("role", "img");
    canvas.tabIndex = 0;
    container.append(canvas);

    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.01, 1e6);
    this.camera.up.set(0, 0, 1); // CAM parts: Z is up (the tool axis)
    this.camera.position.set(1, -1.5, 1);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x404048, 1.6));
    this.light = new THREE.DirectionalLight(0xffffff, 1.6);
    this.camera.add(this.light);
    this.light.position.set(0.5, 1, 0.2);
    this.scene.add(this.camera);

    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.enableDamping = false;
    this.controls.screenSpacePanning = true;
    this.controls.listenToKeyEvents(canvas); // arrow keys pan when the canvas has focus
    this.controls.addEventListener("change", () => this.requestRender());
    canvas.addEventListener("keydown", (e) => {
      if (e.key === "f" || e.key === "F") { this.fit(); e.preventDefault(); }
      if (e.key === "+" || e.key === "=") { this.zoom(0.8); e.preventDefault(); }
      if (e.key === "-") { this.zoom(1.25); e.preventDefault(); }
    });

    this.layers = new Map();
    this.frame = 0;
    this.resizeObserver = new ResizeObserver(() => this.resize());
    this.resizeObserver.observe(container);
    this.resize();
  }

  resize() {
    const w = Math.max(1, this.container.clientWidth), hgt = Math.max(1, this.container.clientHeight);
    this.renderer.setSize(w, hgt, false);
    this.renderer.domElement.style.width = "100%";
    this.renderer.domElement.style.height = "100%";
    this.camera.aspect = w / hgt;
    this.camera.updateProjectionMatrix();
    this.requestRender();
  }

  requestRender() {
    if (this.frame) return;
    this.frame = requestAnimationFrame(() => {
      this.frame = 0;
      this.renderer.render(this.scene, this.camera);
      this.container.dataset.rendered = String((Number(this.container.dataset.rendered) || 0) + 1);
    });
  }

  setLayer(name, object) {
    this.removeLayer(name);
    this.layers.set(name, object);
    this.scene.add(object);
    this.requestRender();
  }

  removeLayer(name) {
    const old = this.layers.get(name);
    if (!old) return;
    this.scene.remove(old);
    old.traverse((o) => {
      o.geometry?.dispose();
      (Array.isArray(o.material) ? o.material : [o.material]).forEach((m) => m?.dispose());
    });
    this.layers.delete(name);
    this.requestRender();
  }

  setVisible(name, visible) {
    const obj = this.layers.get(name);
    if (obj) { obj.visible = visible; this.requestRender(); }
  }

  bounds() {
    const box = new THREE.Box3();
    for (const obj of this.layers.values()) if (obj.visible) box.expandByObject(obj);
    return box;
  }

  /** Frame everything visible, looking from the front-right and above (an isometric-ish CAM view). */
  fit() {
    const box = this.bounds();
    if (box.isEmpty()) return;
    const sphere = box.getBoundingSphere(new THREE.Sphere());
    const r = Math.max(sphere.radius, 1e-6);
    const fov = THREE.MathUtils.degToRad(this.camera.fov);
    const dist = r / Math.sin(Math.min(fov, fov * this.camera.aspect) / 2) * 1.05;
    const dir = new THREE.Vector3(0.9, -1.4, 1.0).normalize();
    this.camera.position.copy(sphere.center).addScaledVector(dir, dist);
    this.camera.near = Math.max(dist / 1000, r / 1e4);
    this.camera.far = dist * 10 + r * 10;
    this.camera.updateProjectionMatrix();
    this.controls.target.copy(sphere.center);
    this.controls.update();
    this.requestRender();
  }

  zoom(factor) {
    const t = this.controls.target;
    this.camera.position.sub(t).multiplyScalar(factor).add(t);
    this.controls.update();
    this.requestRender();
  }

  dispose() {
    cancelAnimationFrame(this.frame);
    this.resizeObserver.disconnect();
    for (const name of [...this.layers.keys()]) this.removeLayer(name);
    this.controls.dispose();
    this.renderer.dispose();
    this.renderer.forceContextLoss?.();
    this.renderer.domElement.remove();
  }
}

// ---------------------------------------------------------------- layer builders

function box3Of(positions) {
  const b = new THREE.Box3();
  b.setFromArray(positions);
  return b;
}

/** A point cloud: file colours, else normals as colours, else height; sized from the density. */
export function pointsLayer(geo) {
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.BufferAttribute(geo.positions, 3));
  const n = geo.positions.length / 3;
  const colors = new Float32Array(n * 3);
  const box = box3Of(geo.positions);
  if (geo.colors) {
    for (let i = 0; i < n * 3; i++) colors[i] = geo.colors[i] / 255;
  } else if (geo.normals) {
    const light = new THREE.Vector3(0.4, -0.5, 0.77).normalize();
    for (let i = 0; i < n; i++) {
      const nx = geo.normals[3 * i], ny = geo.normals[3 * i + 1], nz = geo.normals[3 * i + 2];
      const shade = 0.35 + 0.65 * Math.abs(nx * light.x + ny * light.y + nz * light.z);
      const t = (geo.positions[3 * i + 2] - box.min.z) / Math.max(1e-9, box.max.z - box.min.z);
      const [r, gg, b] = heatColor(0.15 + 0.7 * t);
      colors[3 * i] = r * shade; colors[3 * i + 1] = gg * shade; colors[3 * i + 2] = b * shade;
    }
  } else {
    for (let i = 0; i < n; i++) {
      const t = (geo.positions[3 * i + 2] - box.min.z) / Math.max(1e-9, box.max.z - box.min.z);
      colors.set(heatColor(0.15 + 0.7 * t), 3 * i);
    }
  }
  g.setAttribute("color", new THREE.BufferAttribute(colors, 3));
  const size = box.getSize(new THREE.Vector3());
  const area = Math.max(size.x * size.y, size.y * size.z, size.x * size.z, 1e-9);
  const spacing = Math.sqrt(area / Math.max(1, n));
  const material = new THREE.PointsMaterial({ size: spacing * 1.6, vertexColors: true, sizeAttenuation: true });
  return new THREE.Points(g, material);
}

/** A triangle mesh, shaded; with per-face colours (faceColors 0..255 or a function face → rgb) when given. */
export function meshLayer(geo, { color = 0xb8c4d0, faceColor = null, vertexColor = null, flat = false } = {}) {
  let g;
  if (faceColor) {
    // Per-face colours need unshared vertices.
    const nt = geo.tris.length / 3;
    const pos = new Float32Array(nt * 9), col = new Float32Array(nt * 9);
    for (let t = 0; t < nt; t++) {
      const c = faceColor(geo.triFace ? geo.triFace[t] : t);
      for (let k = 0; k < 3; k++) {
        const v = geo.tris[3 * t + k];
        pos.set(geo.positions.subarray(3 * v, 3 * v + 3), 9 * t + 3 * k);
        col.set(c, 9 * t + 3 * k);
      }
    }
    g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(pos, 3));
    g.setAttribute("color", new THREE.BufferAttribute(col, 3));
  } else {
    g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(geo.positions, 3));
    g.setIndex(new THREE.BufferAttribute(geo.tris, 1));
    if (vertexColor) g.setAttribute("color", new THREE.BufferAttribute(vertexColor, 3));
  }
  g.computeVertexNormals();
  const material = new THREE.MeshStandardMaterial({
    color: faceColor || vertexColor ? 0xffffff : color, vertexColors: Boolean(faceColor || vertexColor),
    side: THREE.DoubleSide, flatShading: flat || Boolean(faceColor), roughness: 0.75, metalness: 0.05,
    polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
  });
  return new THREE.Mesh(g, material);
}

export function edgesLayer(positions, edges, color = 0x9fd3ff, opacity = 0.9) {
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.BufferAttribute(positions, 3));
  g.setIndex(new THREE.BufferAttribute(edges, 1));
  return new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color, transparent: opacity < 1, opacity }));
}

/** Quad mesh as wireframe over a faint surface so depth reads well. */
export function quadsLayer(geo) {
  const group = new THREE.Group();
  group.add(meshLayer(geo, { color: 0x3a4452 }));
  group.add(edgesLayer(geo.positions, geo.edges, 0x9fd3ff));
  return group;
}

/** Quads coloured by patch (patches.json), the base in its own colour, sharp edges in red. */
export function patchesLayer(geo, patchesDoc) {
  const facePatch = new Int32Array(geo.faceCount).fill(-1);
  for (const p of patchesDoc.patches || []) for (const f of p.faces || []) if (f < facePatch.length) facePatch[f] = p.id;
  for (const f of patchesDoc.base_faces || []) if (f < facePatch.length) facePatch[f] = -2;
  const group = new THREE.Group();
  group.add(meshLayer(geo, { faceColor: (f) => (facePatch[f] === -2 ? BASE_COLOR : facePatch[f] === -1 ? UNASSIGNED_COLOR : patchColor(facePatch[f])) }));
  if (geo.edges) group.add(edgesLayer(geo.positions, geo.edges, 0x000000, 0.18));
  const sharp = (patchesDoc.sharp_edges || []).flat().filter((v) => Number.isInteger(v) && v < geo.vertexCount);
  if (sharp.length) group.add(edgesLayer(geo.positions, Uint32Array.from(sharp), 0xff3b30));
  return group;
}

/** segments.ply: faces coloured by patch in the file itself. */
export function segmentsLayer(geo) {
  if (!geo.faceColors) {
    const key = Object.keys(geo.faceScalars).find((k) => /patch|segment|label/i.test(k));
    const ids = key ? geo.faceScalars[key] : null;
    return meshLayer(geo, ids ? { faceColor: (f) => patchColor(Math.round(ids[f])) } : {});
  }
  const fc = geo.faceColors;
  return meshLayer(geo, { faceColor: (f) => [fc[3 * f] / 255, fc[3 * f + 1] / 255, fc[3 * f + 2] / 255] });
}

export function surfacesLayer(geo) {
  const n = geo.positions.length / 3;
  const colors = new Float32Array(n * 3);
  for (let i = 0; i < n; i++) colors.set(patchColor(geo.vertexPatch[i]), 3 * i);
  return meshLayer(geo, { vertexColor: colors });
}

/** Machine frame → part frame: p = Rᵀ (m − t), DESIGN's setup.json transform inverted. */
export function machineToPart(setup) {
  const R = setup?.rotation, t = setup?.translation;
  if (!Array.isArray(R) || R.length !== 3 || !Array.isArray(t)) return null;
  const m = new THREE.Matrix4().set(
    R[0][0], R[0][1], R[0][2], t[0], R[1][0], R[1][1], R[1][2], t[1], R[2][0], R[2][1], R[2][2], t[2], 0, 0, 0, 1);
  return m.invert();
}

/** toolpath.json cutting passes (per patch colour) and G-code rapids (dashed), per setup, in the part frame. */
export function toolpathsLayer({ toolpath, setups, gcode }) {
  const group = new THREE.Group();
  const setupById = new Map((setups || []).map((s) => [s.id, s]));
  for (const s of toolpath?.setups || []) {
    const pos = [], col = [];
    for (const p of s.patches || []) {
      const c = patchColor(p.patch);
      for (const pass of p.passes || []) {
        for (let k = 0; k + 1 < pass.length; k++) {
          pos.push(...pass[k], ...pass[k + 1]);
          col.push(...c, ...c);
        }
      }
    }
    if (!pos.length) continue;
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.Float32BufferAttribute(pos, 3));
    g.setAttribute("color", new THREE.Float32BufferAttribute(col, 3));
    const lines = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ vertexColors: true }));
    lines.name = `setup-${s.id}-cuts`;
    lines.userData = { setup: s.id, kind: "cuts" };
    const m = machineToPart(setupById.get(s.id));
    if (m) lines.applyMatrix4(m);
    group.add(lines);
  }
  for (const { setup, parsed, fallbackCuts } of gcode || []) {
    const m = machineToPart(setupById.get(setup));
    if (parsed.rapids.length) {
      const g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(parsed.rapids, 3));
      const r = new THREE.LineSegments(g, new THREE.LineDashedMaterial({ color: 0xffd60a, dashSize: 1, gapSize: 1 }));
      r.userData = { setup, kind: "rapids" };
      if (m) r.applyMatrix4(m);
      g.computeBoundingSphere();
      const rad = g.boundingSphere?.radius || 10;
      r.material.dashSize = rad / 80; r.material.gapSize = rad / 80;
      r.computeLineDistances();
      group.add(r);
    }
    if (fallbackCuts && parsed.cuts.length) { // no toolpath.json for this setup: the program's cutting moves
      const g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(parsed.cuts, 3));
      const c = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color: 0x4cc9f0 }));
      c.userData = { setup, kind: "cuts" };
      if (m) c.applyMatrix4(m);
      group.add(c);
    }
  }
  return group;
}

/** The setup sheet's coverage colours (cam/verify/report.py): finished, over target, not cut, unreachable. */
export const COVERAGE_COLORS = [[0.23, 0.66, 0.36], [0.95, 0.66, 0.1], [0.84, 0.27, 0.27], [0.55, 0.6, 0.66]];

/** The part under the tool paths, see-through: coloured by what verify measured (scallop.ply's values, NaN
 * unreachable, negative never cut) when `values` is given, else plain. */
export function partUnderLayer(geo, values, target) {
  let vertexColor = null;
  if (values && typeof target === "number") {
    const n = geo.positions.length / 3;
    vertexColor = new Float32Array(n * 3);
    for (let i = 0; i < n; i++) {
      const v = values[i];
      const k = Number.isNaN(v) ? 3 : v < 0 ? 2 : v <= target * (1 + 1e-9) ? 0 : 1;
      vertexColor.set(COVERAGE_COLORS[k], 3 * i);
    }
  }
  const mesh = meshLayer(geo, vertexColor ? { vertexColor } : { color: 0xc9d6e3 });
  Object.assign(mesh.material, { transparent: true, opacity: 0.5, depthWrite: false });
  mesh.renderOrder = -1;
  mesh.userData = { kind: "part" };
  return mesh;
}

/** scallop.ply as a heat map: the scalar per vertex mapped over [lo, hi] mm; NaN or negative = not reached. */
export function heatmapLayer(geo, values, lo, hi) {
  const n = geo.positions.length / 3;
  const colors = new Float32Array(n * 3);
  const span = Math.max(1e-12, hi - lo);
  for (let i = 0; i < n; i++) {
    const v = values[i];
    colors.set(Number.isFinite(v) && v >= 0 ? heatColor((v - lo) / span) : UNREACHED_COLOR, 3 * i);
  }
  if (!geo.tris) { // a cloud of samples: draw them as points
    return pointsLayer({ ...geo, colors: Uint8Array.from(colors, (v) => v * 255), normals: null });
  }
  return meshLayer(geo, { vertexColor: colors });
}
