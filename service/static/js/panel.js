// The job page's 3D panel: one toggle per artifact view, lazy loading with progress, parsing in a worker,
// a colour bar for the scallop heat map. Without WebGL (or without the vendored three.js) it says so and
// the rest of the page carries on.

import { fetchArtifact } from "./api.js";
import { BASE_COLOR, heatGradientCss, patchCss } from "./colors.js";
import { formatBytes, formatNumber, h } from "./util.js";

/** Points drawn at most; a larger cloud is thinned evenly for display (the download is the full file). */
export const POINT_BUDGET = 400_000;

export function webglAvailable() {
  try {
    const c = document.createElement("canvas");
    return Boolean((window.WebGL2RenderingContext && c.getContext("webgl2"))
      || (window.WebGLRenderingContext && c.getContext("webgl")));
  } catch {
    return false;
  }
}

const programNames = (arts) => [...arts.keys()].filter((n) => /^program(-setup\d+)?(-rest)?\.nc$/.test(n)).sort();

/** The views, in pipeline order. `ready(arts)` says whether the artifacts it needs exist. */
const VIEWS = [
  { key: "cloud", label: "Point cloud", ready: (a) => a.has("cloud.ply") },
  { key: "mesh_raw", label: "Raw mesh", ready: (a) => a.has("mesh_raw.ply") },
  { key: "mesh", label: "Denoised mesh", ready: (a) => a.has("mesh.ply") },
  { key: "quads", label: "Quad mesh", ready: (a) => a.has("quads.obj") },
  { key: "patches", label: "Patches", ready: (a) => (a.has("quads.obj") && a.has("patches.json")) || a.has("segments.ply") },
  { key: "surfaces", label: "Surfaces", ready: (a) => a.has("surfaces.json") },
  { key: "toolpaths", label: "Tool paths", ready: (a) => a.has("toolpath.json") || programNames(a).length > 0 },
  { key: "scallop", label: "Scallop heat map", ready: (a) => a.has("scallop.ply") },
];

// --------------------------------------------------------------- parsing off the main thread

let worker = null, workerFailed = false, nextId = 1;
const pending = new Map();

function getWorker() {
  if (worker || workerFailed) return worker;
  try {
    worker = new Worker(new URL("./parse-worker.js", import.meta.url), { type: "module" });
    worker.onmessage = (e) => {
      const p = pending.get(e.data.id);
      if (!p) return;
      pending.delete(e.data.id);
      if (e.data.error) p.reject(new Error(e.data.error)); else p.resolve(e.data.result);
    };
    worker.onerror = (e) => {
      e.preventDefault?.();
      workerFailed = true;
      worker = null;
      for (const p of pending.values()) p.retry();
      pending.clear();
    };
  } catch {
    workerFailed = true;
  }
  return worker;
}

async function parse(task, buffer, options = {}) {
  const inline = async () => (await import("./parse-worker.js")).runTask(task, buffer, options);
  const w = getWorker();
  if (!w) return inline();
  return new Promise((resolve, reject) => {
    const id = nextId++;
    const copy = buffer.slice(0); // the worker takes its own copy; ours stays usable for a fallback
    pending.set(id, { resolve, reject, retry: () => inline().then(resolve, reject) });
    w.postMessage({ id, task, payload: copy, options }, [copy]);
  });
}

// --------------------------------------------------------------- the panel

export class ViewerPanel {
  constructor(job) {
    this.job = job;
    this.arts = new Map();
    this.buttons = new Map();
    this.state = new Map(); // key -> {on, loaded, loading, error, sig}
    this.viewer = null;
    this.mod = null;
    this.jsonCache = new Map();
    this.destroyed = false;
    this.autoPicked = false;
    this.webgl = webglAvailable();

    this.info = h("p.viewer-info", { "aria-live": "polite" });
    this.overlay = h("div.viewer-overlay", { hidden: true });
    this.colorbar = h("div.colorbar", { hidden: true });
    this.viewport = h("div.viewport", { dataset: { state: "idle", layers: "" } }, this.overlay, this.colorbar);
    this.toolbar = h("div.toolbar", { role: "toolbar", "aria-label": "3D views" });
    for (const v of VIEWS) {
      const b = h("button.toggle", { type: "button", "aria-pressed": "false", dataset: { view: v.key },
        onclick: () => this.toggle(v.key) }, v.label);
      this.buttons.set(v.key, b);
      this.toolbar.append(b);
    }
    this.rapids = h("input", { type: "checkbox", id: "show-rapids", checked: true,
      onchange: () => this._applySubToggles() });
    this.partBox = h("input", { type: "checkbox", id: "show-part", checked: true,
      onchange: () => this._applySubToggles() });
    this.setupBox = h("span.setup-toggles");
    this.hiddenSetups = new Set();
    this.tools = h("div.toolbar.secondary", { role: "toolbar", "aria-label": "View" },
      h("button", { type: "button", onclick: () => this.viewer?.fit(), title: "Frame everything shown (F)" }, "Fit view"),
      h("button", { type: "button", onclick: () => this.viewer?.zoom(0.8), "aria-label": "Zoom in" }, "+"),
      h("button", { type: "button", onclick: () => this.viewer?.zoom(1.25), "aria-label": "Zoom out" }, "−"),
      h("label.check", this.rapids, " rapids"), h("label.check", this.partBox, " part under the paths"), this.setupBox);
    this.el = h("section.card.viewer-card", { "aria-labelledby": "viewer-title" },
      h("h2#viewer-title", "3D view"), this.toolbar, this.tools, this.viewport, this.info);
    if (!this.webgl) this._noWebgl("3D views need WebGL, which this browser does not offer. Progress, results and downloads still work.");
  }

  _noWebgl(message) {
    this.webgl = false;
    this.viewport.dataset.state = "nowebgl";
    this.viewport.classList.add("empty");
    this.overlay.hidden = false;
    this.overlay.textContent = message;
    for (const b of this.buttons.values()) b.disabled = true;
    for (const b of this.tools.querySelectorAll("button, input")) b.disabled = true;
  }

  /** New job body from polling: enable the views whose artifacts exist, reload a view whose files changed. */
  update(job) {
    this.job = job;
    this.arts = new Map(job.artifacts.map((a) => [a.name, a]));
    for (const v of VIEWS) {
      const ok = v.ready(this.arts);
      const b = this.buttons.get(v.key);
      b.disabled = !this.webgl || !ok;
      b.title = ok ? `Show or hide the ${v.label.toLowerCase()}` : "not produced (yet) by this job";
      const st = this.state.get(v.key);
      if (st?.on && ok && st.sig !== this._signature(v.key)) this._load(v.key);
    }
    if (!this.autoPicked && this.webgl) {
      // Start with the most downstream surface-like view that exists, plus the tool paths.
      const pick = ["scallop", "surfaces", "patches", "mesh", "mesh_raw", "cloud"].find((k) => VIEWS.find((v) => v.key === k).ready(this.arts));
      if (pick) {
        this.autoPicked = true;
        this.toggle(pick, true);
        if (pick !== "scallop" && VIEWS.find((v) => v.key === "toolpaths").ready(this.arts)) this.toggle("toolpaths", true);
      }
    }
  }

  _signature(key) {
    const names = {
      cloud: ["cloud.ply"], mesh_raw: ["mesh_raw.ply"], mesh: ["mesh.ply"], quads: ["quads.obj"],
      patches: ["quads.obj", "patches.json", "segments.ply"], surfaces: ["surfaces.json"],
      toolpaths: ["toolpath.json", "setup.json", ...programNames(this.arts), "scallop.ply", "mesh.ply"], scallop: ["scallop.ply"],
    }[key];
    return names.map((n) => this.arts.get(n)?.sha256 || "").join(",");
  }

  toggle(key, force) {
    if (!this.webgl) return;
    const st = this.state.get(key) || { on: false };
    st.on = force === undefined ? !st.on : force;
    this.state.set(key, st);
    this.buttons.get(key).setAttribute("aria-pressed", String(st.on));
    if (st.on && st.sig !== this._signature(key) && !st.loading) this._load(key);
    else if (this.viewer) this.viewer.setVisible(key, st.on);
    this._refreshState();
  }

  async _ensureViewer() {
    if (this.viewer) return this.viewer;
    if (!this.mod) {
      try {
        this.mod = await import("./viewer.js");
      } catch (err) {
        this._noWebgl("The 3D viewer could not load three.js (service/static/vendor/three/; run scripts/vendor_three.sh). "
          + "Progress, results and downloads still work.");
        throw err;
      }
    }
    if (this.destroyed) throw new Error("closed");
    try {
      this.viewer = new this.mod.Viewer(this.viewport);
    } catch (err) {
      this._noWebgl(`3D views could not start WebGL (${err.message}). Progress, results and downloads still work.`);
      throw err;
    }
    return this.viewer;
  }

  async _bytes(name, label) {
    const a = this.arts.get(name);
    if (!a) throw new Error(`${name} is missing`);
    this._progress(`${label}: downloading ${name} (${formatBytes(a.size_bytes)})…`, 0);
    return fetchArtifact(a.url, { onProgress: (f) => this._progress(`${label}: downloading ${name}…`, f) });
  }

  async _json(name) {
    const a = this.arts.get(name);
    if (!a) return null;
    const key = a.sha256;
    if (!this.jsonCache.has(key)) {
      this.jsonCache.set(key, fetchArtifact(a.url).then((buf) => JSON.parse(new TextDecoder().decode(buf))));
    }
    return this.jsonCache.get(key);
  }

  _progress(text, fraction) {
    this.overlay.hidden = false;
    this.overlay.textContent = "";
    this.overlay.append(h("span", text));
    if (fraction !== null && fraction !== undefined) {
      const bar = h("div.progress", { role: "progressbar", "aria-valuemin": "0", "aria-valuemax": "100",
        "aria-valuenow": String(Math.round(fraction * 100)), "aria-label": "download" }, h("div.fill"));
      bar.firstChild.style.width = `${Math.round(fraction * 100)}%`;
      this.overlay.append(bar);
    }
  }

  async _load(key) {
    const st = this.state.get(key);
    const sig = this._signature(key);
    st.loading = true;
    st.error = null;
    this._refreshState();
    const label = VIEWS.find((v) => v.key === key).label;
    try {
      const viewer = await this._ensureViewer();
      const { object, info, colorbar, setups } = await this._build(key, label);
      if (this.destroyed) return;
      const first = viewer.layers.size === 0;
      viewer.setLayer(key, object);
      viewer.setVisible(key, this.state.get(key).on);
      st.sig = sig;
      st.info = info;
      st.colorbar = colorbar;
      if (key === "toolpaths") this._setupToggles(setups);
      if (first) viewer.fit();
    } catch (err) {
      if (this.destroyed || err.message === "closed") return;
      st.error = `${label}: ${err.message}`;
      st.on = false;
      this.buttons.get(key).setAttribute("aria-pressed", "false");
    } finally {
      st.loading = false;
      this._refreshState();
    }
  }

  async _build(key, label) {
    const m = this.mod;
    const parsing = () => this._progress(`${label}: reading…`, null);
    if (key === "cloud") {
      const buf = await this._bytes("cloud.ply", label);
      parsing();
      const geo = await parse("ply", buf, { pointBudget: POINT_BUDGET });
      const shown = geo.shownCount ?? geo.vertexCount;
      return { object: m.pointsLayer(geo),
        info: shown < geo.vertexCount
          ? `${formatNumber(geo.vertexCount)} points; showing ${formatNumber(shown)} (thinned for display)`
          : `${formatNumber(geo.vertexCount)} points${geo.normals ? " with normals" : ""}` };
    }
    if (key === "mesh_raw" || key === "mesh") {
      const name = `${key}.ply`;
      const buf = await this._bytes(name, label);
      parsing();
      const geo = await parse("ply", buf);
      if (!geo.tris) throw new Error(`${name} has no faces`);
      return { object: m.meshLayer(geo, { color: key === "mesh" ? 0xc9d6e3 : 0xd9c6a5 }),
        info: `${label}: ${formatNumber(geo.vertexCount)} vertices, ${formatNumber(geo.faceCount)} faces` };
    }
    if (key === "quads") {
      const buf = await this._bytes("quads.obj", label);
      parsing();
      const geo = await parse("obj", buf, { wantEdges: true });
      return { object: m.quadsLayer(geo),
        info: `Quad mesh: ${formatNumber(geo.faceCount)} faces (${formatNumber(geo.quadCount)} quads), ${formatNumber(geo.vertexCount)} vertices` };
    }
    if (key === "patches") {
      if (this.arts.has("quads.obj") && this.arts.has("patches.json")) {
        const [buf, doc] = [await this._bytes("quads.obj", label), await this._json("patches.json")];
        parsing();
        const geo = await parse("obj", buf, { wantEdges: true });
        const n = (doc.patches || []).length;
        return { object: m.patchesLayer(geo, doc),
          info: `${n} patches, ${formatNumber((doc.base_faces || []).length)} base faces (grey), `
            + `${formatNumber((doc.sharp_edges || []).length)} sharp edges (red)`,
          colorbar: { legend: (doc.patches || []).slice(0, 24).map((p) => ({ id: p.id, sharp: p.sharp_boundary })) } };
      }
      const buf = await this._bytes("segments.ply", label);
      parsing();
      const geo = await parse("ply", buf);
      if (!geo.tris) throw new Error("segments.ply has no faces");
      return { object: m.segmentsLayer(geo), info: `Patches from segments.ply: ${formatNumber(geo.faceCount)} faces` };
    }
    if (key === "surfaces") {
      const buf = await this._bytes("surfaces.json", label);
      parsing();
      const geo = await parse("surfaces", buf, { res: 24 });
      if (!geo.surfaceCount) throw new Error(geo.errors[0] || "no surface could be drawn");
      // The tolerance the fit stage used, as it wrote it (JobParams derives it when fit.tolerance_mm is unset).
      const tol = geo.tolerance;
      return { object: m.surfacesLayer(geo),
        info: `${geo.surfaceCount} B-spline surfaces${geo.maxError !== null ? `, max fit error ${formatNumber(geo.maxError)} mm` : ""}`
          + `${tol !== null ? ` (tolerance ${tol} mm)` : ""}${geo.errors.length ? `; ${geo.errors.length} not drawn: ${geo.errors[0]}` : ""}` };
    }
    if (key === "toolpaths") {
      const toolpath = await this._json("toolpath.json");
      const setupDoc = await this._json("setup.json");
      const setups = setupDoc?.setups || [];
      const programs = programNames(this.arts);
      const pathSetups = new Set((toolpath?.setups || []).map((s) => s.id));
      const gcode = [];
      for (const name of programs) {
        const setup = setups.find((s) => s.program === name || s.rest_program === name)?.id
          ?? (/^program(-rest)?\.nc$/.test(name) ? (setups[0]?.id ?? 0) : Number(/setup(\d+)/.exec(name)?.[1]));
        const buf = await this._bytes(name, label);
        parsing();
        const parsed = await parse("gcode", buf);
        gcode.push({ setup, parsed, fallbackCuts: !pathSetups.has(setup) });
      }
      const object = m.toolpathsLayer({ toolpath, setups, gcode });
      const under = await this._partUnder(label);
      if (under) object.add(under.object);
      let passes = 0;
      const certified = [];
      for (const s of toolpath?.setups || []) {
        for (const p of s.patches || []) {
          passes += (p.passes || []).length;
          if (typeof p.certified_scallop_mm === "number") certified.push(p.certified_scallop_mm);
        }
      }
      const rapids = gcode.reduce((n, g) => n + g.parsed.rapids.length / 6, 0);
      const setupIds = [...new Set([...(toolpath?.setups || []).map((s) => s.id), ...gcode.map((g) => g.setup)])];
      return { object, setups: setupIds.length > 1 ? setupIds : null, info: `${Math.max(setups.length, (toolpath?.setups || []).length, 1)} setup(s), ${formatNumber(passes)} passes`
        + `${certified.length ? `, certified scallop ≤ ${formatNumber(Math.max(...certified))} mm` : ""}`
        + `${gcode.length ? `, ${formatNumber(rapids)} rapid moves (dashed) from ${programs.join(", ")}` : ""}`
        + `${under ? `; the part under them${under.coloured ? " as verify measured it: green finished, amber over "
          + "target, red not cut, grey unreachable" : ""}` : ""}` };
    }
    if (key === "scallop") {
      const buf = await this._bytes("scallop.ply", label);
      parsing();
      const geo = await parse("ply", buf, { pointBudget: POINT_BUDGET });
      const names = Object.keys(geo.scalars);
      const field = names.find((n) => /scallop/i.test(n)) || names.find((n) => /height|value|quality|scalar|error/i.test(n)) || names[0];
      const target = this.job.params?.toolpath?.scallop_height_mm;
      if (!field) {
        if (!geo.colors) throw new Error("scallop.ply has no scalar property and no colours");
        return { object: geo.tris ? m.meshLayer(geo, { vertexColor: Float32Array.from(geo.colors, (c) => c / 255) }) : m.pointsLayer(geo),
          info: "Scallop heat map (colours from the file)" };
      }
      const vals = geo.scalars[field];
      let hi = 0, unreached = 0;
      for (const v of vals) if (Number.isFinite(v) && v >= 0) hi = Math.max(hi, v); else unreached++;
      const lo = 0;
      const top = Math.max(hi, typeof target === "number" ? target : 0) || 1;
      const verify = this.arts.has("verify.json") ? await this._json("verify.json") : null;
      const summary = typeof verify?.summary === "string" ? `${verify.summary}. ` : "";
      return { object: m.heatmapLayer(geo, vals, lo, top),
        info: `${summary}Scallop (${field}): max ${formatNumber(hi)} mm${typeof target === "number" ? `, target ${target} mm` : ""}`
          + `${unreached ? `; ${formatNumber(unreached)} vertices not reached (grey)` : ""}`
          + `${(geo.shownCount ?? geo.vertexCount) < geo.vertexCount ? `; showing ${formatNumber(geo.shownCount)} of ${formatNumber(geo.vertexCount)} samples` : ""}`,
        colorbar: { lo, hi: top, target, max: hi } };
    }
    throw new Error(`no view ${key}`);
  }

  /** The part to draw under the tool paths: scallop.ply (coloured by coverage) or else mesh.ply; null if neither. */
  async _partUnder(label) {
    const name = ["scallop.ply", "mesh.ply"].find((n) => this.arts.has(n));
    if (!name) return null;
    const buf = await this._bytes(name, label);
    const geo = await parse("ply", buf);
    if (!geo.tris) return null;
    const field = Object.keys(geo.scalars || {}).find((n) => /scallop/i.test(n));
    const target = this.job.params?.toolpath?.scallop_height_mm;
    const coloured = Boolean(field) && typeof target === "number";
    return { object: this.mod.partUnderLayer(geo, coloured ? geo.scalars[field] : null, target), coloured };
  }

  _setupToggles(ids) {
    this.setupBox.replaceChildren(...(ids || []).map((id) => h("label.check", h("input", { type: "checkbox",
      checked: !this.hiddenSetups.has(id), onchange: (e) => {
        if (e.target.checked) this.hiddenSetups.delete(id); else this.hiddenSetups.add(id);
        this._applySubToggles();
      } }), ` setup ${id}`)));
  }

  _applySubToggles() {
    const obj = this.viewer?.layers.get("toolpaths");
    if (!obj) return;
    obj.traverse((o) => {
      if (!o.userData?.kind) return;
      // the part under the paths gives way to the heat map, which draws the same surface
      o.visible = o.userData.kind === "part" ? this.partBox.checked && !this.state.get("scallop")?.on
        : !this.hiddenSetups.has(o.userData.setup) && (o.userData.kind !== "rapids" || this.rapids.checked);
    });
    this.viewer.requestRender();
  }

  _refreshState() {
    if (!this.webgl) return;
    const on = [...this.state.entries()].filter(([, s]) => s.on);
    const loading = on.some(([, s]) => s.loading);
    const errors = [...this.state.values()].map((s) => s.error).filter(Boolean);
    const loaded = on.filter(([, s]) => s.sig && !s.loading).map(([k]) => k);
    this.viewport.dataset.state = loading ? "loading" : errors.length && !loaded.length ? "error" : loaded.length ? "ready" : "idle";
    this.viewport.dataset.layers = loaded.join(",");
    if (!loading) this.overlay.hidden = true;
    this.viewport.classList.toggle("empty", !loaded.length && !loading);
    if (!loaded.length && !loading && !errors.length) {
      this.overlay.hidden = false;
      this.overlay.textContent = this.arts.size ? "Nothing to show yet: the 3D views appear as the stages write their artifacts."
        : "No artifacts yet.";
    }
    this._applySubToggles();
    this.info.textContent = "";
    for (const [, s] of on) if (s.info && !s.loading) this.info.append(h("span", s.info), h("br"));
    for (const e of errors) this.info.append(h("span.error-text", e), h("br"));
    this._colorbar(on.map(([, s]) => s.colorbar).filter(Boolean));
  }

  _colorbar(bars) {
    const cb = this.colorbar;
    cb.textContent = "";
    const heat = bars.find((b) => b.lo !== undefined);
    const legend = bars.find((b) => b.legend);
    cb.hidden = !heat && !legend;
    if (heat) {
      const ramp = h("div.ramp", { role: "img", "aria-label": `scallop height from ${formatNumber(heat.lo)} to ${formatNumber(heat.hi)} mm` });
      ramp.style.background = heatGradientCss();
      if (typeof heat.target === "number" && heat.hi > heat.lo) {
        const mark = h("span.target", { title: `target ${heat.target} mm` });
        mark.style.left = `${(100 * (heat.target - heat.lo)) / (heat.hi - heat.lo)}%`;
        ramp.append(mark);
      }
      cb.append(h("div.cb-title", "scallop height (mm)"), ramp,
        h("div.cb-labels", h("span", formatNumber(heat.lo)),
          typeof heat.target === "number" ? h("span", `target ${heat.target}`) : null,
          h("span", formatNumber(heat.hi))));
    }
    if (legend) {
      const base = h("span.swatch");
      base.style.background = `rgb(${BASE_COLOR.map((c) => Math.round(c * 255)).join(" ")})`;
      const items = legend.legend.map((p) => {
        const sw = h("span.swatch");
        sw.style.background = patchCss(p.id);
        return h("span.legend-item", sw, `${p.id}`);
      });
      cb.append(h("div.cb-title", "patches"), h("div.legend", h("span.legend-item", base, "base"), items));
    }
  }

  destroy() {
    this.destroyed = true;
    this.viewer?.dispose();
    this.viewer = null;
  }
}
