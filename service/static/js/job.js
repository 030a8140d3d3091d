// The job page (#/jobs/{id}): status and per-stage progress (polled while it runs), the verification and
// ingest summaries, the 3D views, downloads, parameters, and cancel / rerun (prefilled) / delete.

import { ApiError, api, apiKey, downloadWithKey, fetchArtifact } from "./api.js";
import { ParamsForm } from "./form.js";
import { paramsSchema, showProblem } from "./newjob.js";
import { ViewerPanel } from "./panel.js";
import { ACTIVE, formatBytes, formatDuration, formatNumber, formatTime, h, progressBar, statusBadge, toast } from "./util.js";

const POLL_MS = 1000;
/** toolpath.json is read for the plan's `partial` / `unmachined` notes only up to this size (it holds every pass). */
const TOOLPATH_JSON_MAX = 8 * 1024 * 1024;

function first(obj, keys) {
  for (const k of keys) {
    const v = k.split(".").reduce((o, p) => (o && typeof o === "object" ? o[p] : undefined), obj);
    if (v !== undefined && v !== null) return v;
  }
  return undefined;
}

/** A job that finishes less than this share of its part is not shown as a success, whatever verify's own
 * criteria (which judge the share of what the ball can reach) say: the base and undercuts may be most of it. */
export const LITTLE_SHARE = 0.5;

/** A share as verify.json's summary writes it (cam/verify/part.py format_share): strictly between 0 and 1 it
 * never reads 0.0 % or 100.0 %, so "100.0 %" means all of it. */
const pctText = (v) => (v > 0 && v < 0.0005 ? "< 0.1 %" : v >= 0.9995 && v < 1 ? "> 99.9 %" : `${(100 * v).toFixed(1)} %`);

/** One verdict on how much of the part the programs finish: verify's pass/fail, its finished share of the
 * reachable against toolpath.min_finished_share, and the finished share of the whole part. */
export function coverageVerdict(doc, params) {
  if (!doc || typeof doc !== "object") return null;
  const fin = doc.finished_share_of_reachable, whole = doc.finished_share;
  const min = doc.min_finished_share ?? params?.toolpath?.min_finished_share;
  if (doc.passed === false) return { cls: "st-failed", text: "not passed" };
  if (typeof fin === "number" && typeof min === "number" && fin < min) {
    return { cls: "st-failed", text: `finishes ${pctText(fin)} of the reachable` };
  }
  if (typeof whole === "number" && whole < LITTLE_SHARE) {
    return { cls: "st-warn", text: `finishes only ${pctText(whole)} of the part` };
  }
  return doc.passed === true ? { cls: "st-succeeded", text: "passed" } : null;
}

/** verify.json's unfinished area by reason, nested as verify measures it, in words, with shares of the part. */
function reasonRows(doc, params) {
  const un = { ...(doc.unfinished_mm2 || {}) };
  const total = typeof doc.area_mm2 === "number" && doc.area_mm2 > 0 ? doc.area_mm2 : null;
  const rest = doc.rest_radius_mm ?? params?.tool?.rest_radius_mm;
  const rows = [];
  const row = (key, label, sub = false) => {
    const v = un[key];
    delete un[key];
    if (typeof v !== "number") return;
    rows.push(h(`tr${sub ? ".sub" : ""}`, { dataset: { reason: key } }, h("th", { scope: "row" }, sub ? `… ${label}` : label),
      h("td.num", `${formatNumber(v)} mm²`), h("td.num", total ? pctText(v / total) : "")));
  };
  row("not_planned_mm2", "reachable, but no program leaves it within the target");
  row("unreachable_by_main_ball_mm2", `the ${formatNumber(doc.tool_radius_mm ?? params?.tool?.radius_mm)} mm ball cannot reach it from any setup`);
  row("finished_outside_main_reach_mm2", "of which finished all the same", true);
  if (rest) row("left_for_rest_tool_mm2", "of which the rest ball reaches, but no program finishes", true);
  else delete un.left_for_rest_tool_mm2;
  row("unreachable_by_any_ball_mm2", rest ? "of which no ball of this job reaches" : "of which no ball reaches (no rest ball is set)", true);
  for (const key of Object.keys(un)) row(key, key.replace(/_mm2$/, "").replaceAll("_", " "));
  return rows;
}

/** The plan's `unmachined` and `partial` entries (setup.json, toolpath.json; top level and per setup), as words. */
export function planNotes(...docs) {
  const seen = new Set(), out = [];
  const add = (where, kind, item) => {
    const text = item && typeof item === "object"
      ? `${item.patch !== undefined ? `patch ${item.patch}` : ""}${typeof item.kept === "number" ? ` (kept ${pctText(item.kept)} of it)` : ""}${item.reason ? ` — ${item.reason}` : ""}`
      : String(item);
    const key = `${kind}|${text}`;
    if (seen.has(key)) return;
    seen.add(key);
    out.push({ where, kind, text: text.replace(/^ — /, "") });
  };
  for (const doc of docs) {
    if (!doc || typeof doc !== "object") continue;
    for (const kind of ["unmachined", "partial"]) for (const it of doc[kind] || []) add("plan", kind, it);
    for (const s of doc.setups || []) for (const kind of ["unmachined", "partial"]) for (const it of s[kind] || []) add(`setup ${s.id}`, kind, it);
  }
  return out;
}

/** verify.json: what the programs leave on the part (mesh.ply) — the finished share of what the ball can reach
 * first, in words, then the unfinished area by reason and what the plan left (`unmachined`, `partial`). */
function verifyCard(doc, params, notes, report) {
  const target = first(doc, ["target_scallop_mm", "target_mm", "scallop_target_mm", "scallop_height_mm"]) ?? params?.toolpath?.scallop_height_mm;
  const max = first(doc, ["max_scallop_mm", "scallop.max_mm", "scallop_max_mm"]);
  const p99 = first(doc, ["p99_scallop_mm", "scallop.p99_mm", "scallop_p99_mm"]);
  const certified = first(doc, ["certified_scallop_mm"]);
  const gouge = first(doc, ["max_gouge_mm", "gouge_mm", "gouge.max_mm"]);
  const rapidGouge = first(doc, ["max_rapid_gouge_mm"]);
  const reachable = first(doc, ["reachable_share"]);
  const finished = first(doc, ["finished_share_of_reachable"]);
  const whole = first(doc, ["finished_share"]);
  const largest = first(doc, ["max_left_on_reachable_mm"]);
  const minShare = first(doc, ["min_finished_share"]) ?? params?.toolpath?.min_finished_share;
  const gougeTol = first(doc, ["gouge_tolerance_mm"]) ?? params?.toolpath?.gouge_tolerance_mm ?? 1e-3;
  const radius = first(doc, ["tool_radius_mm"]) ?? params?.tool?.radius_mm;
  const within = typeof max === "number" && typeof target === "number" ? max <= target * (1 + 1e-6) + 1e-9 : undefined;
  const verdict = coverageVerdict(doc, params);
  const problems = Array.isArray(doc.problems) ? doc.problems : [];
  const tile = (label, value, unit, cls = "") => h(`div.metric${cls}`, h("div.metric-label", label),
    h("div.metric-value", value === undefined || value === null ? "—" : typeof value === "number" ? formatNumber(value) : String(value),
      unit && typeof value === "number" ? h("span.unit", ` ${unit}`) : null));
  const programs = Array.isArray(doc.programs) ? doc.programs : Array.isArray(doc.setups) ? doc.setups : [];
  const finishedBad = typeof finished === "number" && typeof minShare === "number" && finished < minShare;
  const wholeCls = typeof whole === "number" ? (whole < LITTLE_SHARE ? ".warn" : "") : "";
  const headline = typeof finished === "number"
    ? `finished ${pctText(finished)} of what a ${formatNumber(radius)} mm ball can reach`
      + (typeof reachable === "number" ? ` (${pctText(reachable)} of the part)` : "")
    : typeof doc.summary === "string" ? doc.summary : null;
  const reasons = reasonRows(doc, params);
  return h("section.card.verify-card", { "aria-labelledby": "verify-title", dataset: { verdict: verdict?.cls || "" } },
    h("div.card-head", h("h2#verify-title", "Verification"),
      verdict ? h(`span.badge.${verdict.cls}#verify-verdict`, verdict.text) : null,
      report ? h("a.sheet-link", report, "Setup sheet") : null),
    headline ? h("p.verify-summary", headline) : null,
    typeof doc.summary === "string" && doc.summary !== headline ? h("p.small.muted", doc.summary) : null,
    h("div.metrics",
      finished !== undefined ? tile("Finished of reachable", pctText(finished), "", finishedBad ? ".bad" : ".good") : null,
      reachable !== undefined ? tile(`Reachable by the ${formatNumber(radius)} mm ball`, pctText(reachable)) : null,
      whole !== undefined ? tile("Finished of the part", pctText(whole), "", wholeCls) : null,
      tile("Max scallop (finished)", max, "mm", within === false ? ".bad" : ""),
      tile("Target", target, "mm"),
      largest !== undefined ? tile("Largest left (reachable)", largest, "mm", typeof largest === "number" && typeof target === "number" && largest > target ? ".bad" : "") : null,
      certified !== undefined && certified !== null ? tile("Certified bound", certified, "mm") : null,
      tile("p99 scallop", p99, "mm"),
      tile("Gouge", gouge, "mm", typeof gouge === "number" && gouge > gougeTol ? ".bad" : ""),
      rapidGouge !== undefined ? tile("Rapid gouge", rapidGouge, "mm", rapidGouge > gougeTol ? ".bad" : "") : null),
    reasons.length ? h("table.kv.reasons", h("caption", "Not finished, by reason"),
      h("thead", h("tr", h("th", { scope: "col" }, "Reason"), h("th", { scope: "col" }, "Area"), h("th", { scope: "col" }, "Of the part"))),
      h("tbody", reasons)) : null,
    notes.length ? h("div.plan-notes", h("h3", "Left by the plan"), h("ul", notes.map((n) =>
      h("li", { dataset: { kind: n.kind } }, h("strong", `${n.where}, ${n.kind}: `), n.text)))) : null,
    problems.length ? h("ul.problems", problems.map((p) => h("li.error-text", String(p)))) : null,
    h("details", h("summary", "All figures"), h("table.kv", h("tbody",
      Object.entries(doc).filter(([, v]) => ["number", "string", "boolean"].includes(typeof v))
        .map(([k, v]) => h("tr", h("th", { scope: "row" }, k), h("td", typeof v === "number" ? formatNumber(v, 6) : String(v))))))),
    programs.length ? h("table.kv", h("caption", "Per program"), h("tbody", programs.map((s) => h("tr",
      h("th", { scope: "row" }, `${s.program ?? `setup ${s.setup}`}`),
      h("td", Object.entries(s).filter(([, v]) => typeof v === "number").map(([k, v]) => `${k} ${formatNumber(v)}`).join(", ")))))) : null);
}

function ingestCard(doc) {
  const bb = doc.bbox_mm || {};
  const size = Array.isArray(bb.size) ? bb.size.map((v) => formatNumber(v)).join(" × ") : "—";
  const dropped = Array.isArray(doc.dropped) ? doc.dropped : [];
  return h("section.card.ingest-card", { "aria-labelledby": "ingest-title" },
    h("h2#ingest-title", "Input"),
    h("div.metrics",
      h("div.metric", h("div.metric-label", doc.kind === "mesh" ? "Vertices kept" : "Points kept"),
        h("div.metric-value", formatNumber(doc.counts?.kept ?? NaN)), h("div.small.muted", `of ${formatNumber(doc.counts?.read ?? NaN)} read`)),
      h("div.metric", h("div.metric-label", "Size"), h("div.metric-value.small-value", size, h("span.unit", " mm"))),
      h("div.metric", h("div.metric-label", "Format"), h("div.metric-value.small-value", `${doc.format || "?"}`),
        h("div.small.muted", `${doc.units || "mm"}${doc.has_normals ? ", normals" : ""}`))),
    dropped.length ? h("ul.small", dropped.map((d) => h("li", typeof d === "string" ? d : `${d.count ?? ""} ${d.reason ?? JSON.stringify(d)}`))) : null,
    (doc.notes || []).length ? h("p.small.muted", (doc.notes || []).join("; ")) : null);
}

function stagesTable(job) {
  return h("table.stages", h("caption.visually-hidden", "Stages"),
    h("thead", h("tr", ["Stage", "Status", "Progress", "Duration", "Details"].map((c) => h("th", { scope: "col" }, c)))),
    h("tbody", job.stages.map((s) => h("tr", { dataset: { stage: s.name, status: s.status } },
      h("th", { scope: "row", "data-label": "Stage" }, s.name),
      h("td", { "data-label": "Status" }, statusBadge(s.status)),
      h("td", { "data-label": "Progress" }, progressBar(s.progress, { label: `${s.name} progress`, status: s.status }),
        h("span.small.muted", ` ${Math.round(s.progress * 100)}%${s.message && s.status === "running" ? ` · ${s.message}` : ""}`)),
      h("td", { "data-label": "Duration" }, s.duration_s !== null ? formatDuration(s.duration_s)
        : s.started_at && s.status === "running" ? `${formatDuration((Date.now() - new Date(s.started_at)) / 1000)}…` : "—"),
      h("td.details", { "data-label": "Details" },
        s.error ? h("div.stage-error", { role: "alert" }, h("strong", `${s.error.title}: `), s.error.detail) : null,
        s.reused_from ? h("span.small", "reused from ", h("a", { href: `#/jobs/${s.reused_from}` }, h("code", s.reused_from.slice(0, 8)))) : null,
        s.attempts > 1 ? h("span.small.muted", ` ${s.attempts} attempts`) : null)))));
}

function downloadsTable(job) {
  if (!job.artifacts.length) return h("p.muted", "No artifacts yet.");
  const needKey = Boolean(apiKey());
  return h("table.downloads", h("caption.visually-hidden", "Artifacts"),
    h("thead", h("tr", ["File", "Stage", "Size"].map((c) => h("th", { scope: "col" }, c)))),
    h("tbody", job.artifacts.map((a) => h("tr", { dataset: { artifact: a.name } },
      h("td", { "data-label": "File" }, h("a", { href: a.url, download: a.name, title: `${a.media_type}, sha256 ${a.sha256}`,
        onclick: needKey ? (e) => { e.preventDefault(); downloadWithKey(a.url, a.name).catch((err) => toast(err.message, "error")); } : undefined }, a.name)),
      h("td", { "data-label": "Stage" }, a.stage),
      h("td.num", { "data-label": "Size", dataset: { bytes: String(a.size_bytes) } }, formatBytes(a.size_bytes))))));
}

function paramsTable(params) {
  const rows = [];
  for (const [g, fields] of Object.entries(params || {})) {
    for (const [k, v] of Object.entries(fields || {})) rows.push(h("tr", h("th", { scope: "row" }, `${g}.${k}`), h("td", JSON.stringify(v))));
  }
  return rows.length ? h("table.kv", h("tbody", rows)) : h("p.muted", "Defaults.");
}

export function jobView(id, root) {
  let job = null, timer = 0, destroyed = false, failures = 0;
  const panel = { current: null };
  const jsonCache = new Map();

  const head = h("section.card.job-head");
  const verifySlot = h("div");
  const ingestSlot = h("div");
  const stagesSlot = h("div");
  const downloadsSlot = h("div");
  const paramsSlot = h("div");
  const rerunSlot = h("div");
  const conn = h("p.error-text", { role: "status", hidden: true });
  const viewerSlot = h("div");
  root.replaceChildren(
    h("nav.crumbs", { "aria-label": "Breadcrumb" }, h("a", { href: "#/" }, "Jobs"), " / ", h("span#crumb-job", id.slice(0, 8))),
    conn, head, rerunSlot, verifySlot,
    h("div.job-grid",
      h("div.col-main", h("section.card", { "aria-labelledby": "stages-title" }, h("h2#stages-title", "Stages"), stagesSlot), viewerSlot),
      h("div.col-side", ingestSlot,
        h("section.card", { "aria-labelledby": "downloads-title" }, h("h2#downloads-title", "Downloads"), downloadsSlot),
        h("section.card", { "aria-labelledby": "params-title" }, h("h2#params-title", "Parameters"), paramsSlot))));

  async function smallJson(name) {
    const a = job.artifacts.find((x) => x.name === name);
    if (!a) return null;
    if (!jsonCache.has(a.sha256)) {
      jsonCache.set(a.sha256, fetchArtifact(a.url).then((b) => JSON.parse(new TextDecoder().decode(b))).catch(() => null));
    }
    return jsonCache.get(a.sha256);
  }

  const cancelBtn = h("button#cancel-job", { type: "button", onclick: (e) => doCancel(e) }, "Cancel");
  const rerunBtn = h("button#rerun-job", { type: "button", "aria-expanded": "false", onclick: () => openRerun() }, "Rerun…");
  const deleteBtn = h("button.danger#delete-job", { type: "button", onclick: () => doDelete() }, "Delete");
  const headInfo = h("div");
  const coverageSlot = h("span#job-coverage");
  head.append(headInfo, h("div.actions", cancelBtn, rerunBtn, deleteBtn));

  function renderHead() {
    cancelBtn.disabled = !ACTIVE.has(job.status);
    rerunBtn.setAttribute("aria-expanded", String(Boolean(rerunSlot.firstChild)));
    headInfo.replaceChildren(...[
      h("div.card-head", h("h1", job.input.name), h("span.badges", h("span#job-status", statusBadge(job.status)), coverageSlot)),
      progressBar(job.progress, { label: "job progress", status: job.status }),
      h("p.meta",
        h("span", "Job ", h("code", { title: "job id" }, job.id)),
        h("span", "created ", h("time", { datetime: job.created_at }, formatTime(job.created_at))),
        h("span", `updated ${formatTime(job.updated_at)}`),
        h("span", `${job.input.format}, ${formatBytes(job.input.size_bytes)}`),
        job.parent_id ? h("span", "rerun of ", h("a", { href: `#/jobs/${job.parent_id}` }, h("code", job.parent_id.slice(0, 8)))) : null,
        h("a", { href: `/v1/jobs/${job.id}`, target: "_blank", rel: "noopener" }, "JSON")),
      job.error ? h("div.problem", { role: "alert" }, h("strong", `${job.error.title}: `), job.error.detail,
        job.error.stage ? h("span.muted", ` (stage ${job.error.stage})`) : null) : null].filter(Boolean));
    document.title = `${job.input.name} · ${job.status} · cloud2cnc`;
  }

  /** The setup sheet's link: opened in a new tab (through a fetch with the key when the API needs one). */
  function reportLink() {
    const a = job.artifacts.find((x) => x.name === "report.html");
    if (!a) return null;
    const needKey = Boolean(apiKey());
    return { href: a.url, target: "_blank", rel: "noopener", title: "report.html: tools, programs, times, coverage (printable)",
      onclick: needKey ? (e) => {
        e.preventDefault();
        fetchArtifact(a.url).then((buf) => {
          const href = URL.createObjectURL(new Blob([buf], { type: "text/html" }));
          window.open(href, "_blank", "noopener");
          setTimeout(() => URL.revokeObjectURL(href), 60000);
        }).catch((err) => toast(err.message, "error"));
      } : undefined };
  }

  async function renderSummaries() {
    const tp = job.artifacts.find((x) => x.name === "toolpath.json");
    const [verify, ingest, setup, toolpath] = await Promise.all([smallJson("verify.json"), smallJson("ingest.json"),
      smallJson("setup.json"), tp && tp.size_bytes <= TOOLPATH_JSON_MAX ? smallJson("toolpath.json") : null]);
    if (destroyed) return;
    verifySlot.replaceChildren(verify ? verifyCard(verify, job.params, planNotes(setup, toolpath), reportLink()) : "");
    ingestSlot.replaceChildren(ingest ? ingestCard(ingest) : "");
    const verdict = coverageVerdict(verify, job.params);
    coverageSlot.replaceChildren(verdict ? h(`span.badge.${verdict.cls}`, { title: "what verify measured on the part" }, verdict.text) : "");
  }

  let lastJob = "", lastArts = "", lastParams = "";
  function render() {
    const sig = JSON.stringify(job);
    const running = job.stages.some((s) => s.status === "running"); // its elapsed time moves on
    if (sig === lastJob && !running) return;
    lastJob = sig;
    renderHead();
    stagesSlot.replaceChildren(stagesTable(job));
    // Lists with links are rebuilt only when they change, so keyboard focus stays where it is.
    const arts = JSON.stringify(job.artifacts);
    if (arts !== lastArts) { lastArts = arts; downloadsSlot.replaceChildren(downloadsTable(job)); }
    const params = JSON.stringify(job.params);
    if (params !== lastParams) { lastParams = params; paramsSlot.replaceChildren(paramsTable(job.params)); }
    if (!panel.current) {
      panel.current = new ViewerPanel(job);
      viewerSlot.replaceChildren(panel.current.el);
    }
    panel.current.update(job);
    renderSummaries();
  }

  let pollGen = 0;
  async function poll() {
    clearTimeout(timer);
    const gen = ++pollGen; // only the latest poll schedules the next one
    try {
      const body = await api.getJob(id);
      if (destroyed || gen !== pollGen) return;
      job = body;
      failures = 0;
      conn.hidden = true;
      render();
    } catch (err) {
      if (destroyed || gen !== pollGen) return;
      if (err instanceof ApiError && err.status === 404) {
        root.replaceChildren(h("nav.crumbs", h("a", { href: "#/" }, "Jobs")),
          h("section.card", h("h1", "Job not found"), h("p", `There is no job ${id}; it may have been deleted.`),
            h("p", h("a", { href: "#/" }, "Back to the jobs"))));
        return;
      }
      failures++;
      conn.textContent = `Lost contact with the server (${err.message}); retrying…`;
      conn.hidden = false;
    }
    if (destroyed) return;
    // A canceled job's running stage stops at its next check: keep polling until every stage has settled.
    const active = !job || ACTIVE.has(job.status) || job.stages.some((st) => ACTIVE.has(st.status));
    const delay = active ? POLL_MS * Math.min(8, 2 ** Math.max(0, failures - 1)) : 15000;
    timer = setTimeout(() => (document.hidden && !active ? (timer = setTimeout(poll, 15000)) : poll()), delay);
  }

  async function doCancel(e) {
    e.target.disabled = true;
    try {
      job = await api.cancel(id);
      toast("Cancel requested: queued stages are dropped, the running stage stops at its next check.");
      render();
      poll();
    } catch (err) {
      toast(err.message, "error");
      e.target.disabled = false;
    }
  }

  async function doDelete() {
    if (!confirm(`Delete job ${id.slice(0, 8)} (${job.input.name}) and the artifacts no other job uses?`)) return;
    try {
      await api.remove(id);
      toast(`Deleted job ${id.slice(0, 8)}.`);
      location.hash = "#/";
    } catch (err) {
      toast(err.message, "error");
    }
  }

  function openRerun() {
    if (rerunSlot.firstChild) { rerunSlot.replaceChildren(); renderHead(); return; }
    const holder = h("div", h("p.muted", "Loading parameters…"));
    const summary = h("div.problem", { role: "alert", hidden: true });
    const submit = h("button.primary", { type: "submit" }, "Start rerun");
    let form = null;
    const el = h("form#rerun-form", { "aria-labelledby": "rerun-title" }, holder, summary,
      h("div.actions", submit, h("button", { type: "button", onclick: () => { rerunSlot.replaceChildren(); renderHead(); } }, "Close")));
    el.addEventListener("submit", async (e) => {
      e.preventDefault();
      summary.hidden = true;
      if (!form) return;
      form.clearErrors();
      if (!el.noValidate && !form.validate()) return;
      submit.disabled = true;
      try {
        const next = await api.rerun(id, form.changes(job.params));
        location.hash = `#/jobs/${next.id}`;
      } catch (err) {
        showProblem(summary, form, err);
      } finally {
        submit.disabled = false;
      }
    });
    rerunSlot.replaceChildren(h("section.card.rerun-card", h("h2#rerun-title", "Rerun with changed parameters"),
      h("p.small.muted", "A new job from the same input; stages whose inputs and parameters did not change are reused."), el));
    renderHead();
    paramsSchema().then((schema) => {
      form = new ParamsForm(schema, job.params, "rerun");
      holder.replaceChildren(form.el);
      form.el.querySelector("input, select")?.focus();
    }, (err) => holder.replaceChildren(h("p.error-text", `The parameter form could not load: ${err.message}`)));
  }

  poll();
  return () => {
    destroyed = true;
    clearTimeout(timer);
    panel.current?.destroy();
  };
}
