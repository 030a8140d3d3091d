// The jobs list: newest first, cursor pagination, status filter, auto-refresh while the page is visible.

import { api } from "./api.js";
import { formatBytes, formatTime, h, relativeTime, shortId, statusBadge } from "./util.js";

const REFRESH_MS = 3000;
const PAGE_SIZE = 20;

function stageStrip(job) {
  const strip = h("div.stage-strip", { role: "img",
    "aria-label": job.stages.map((s) => `${s.name} ${s.status}`).join(", ") });
  for (const s of job.stages) {
    const seg = h(`span.seg.st-${s.status}`, { title: `${s.name}: ${s.status}${s.status === "running" ? ` ${Math.round(s.progress * 100)}%` : ""}` });
    if (s.status === "running") {
      const fill = h("span.seg-fill");
      fill.style.width = `${Math.round(s.progress * 100)}%`;
      seg.append(fill);
    }
    strip.append(seg);
  }
  return strip;
}

function row(job) {
  const href = `#/jobs/${job.id}`;
  const done = job.stages.filter((s) => ["succeeded", "skipped"].includes(s.status)).length;
  return h("tr", { dataset: { jobId: job.id, status: job.status } },
    h("td.id", { "data-label": "Job" }, h("a", { href, title: job.id }, h("code", shortId(job.id)))),
    h("td", { "data-label": "Status" }, statusBadge(job.status)),
    h("td", { "data-label": "Created" }, h("time", { datetime: job.created_at, title: new Date(job.created_at).toLocaleString() },
      formatTime(job.created_at)), h("span.muted.small", ` ${relativeTime(job.created_at)}`)),
    h("td.input", { "data-label": "Input" }, h("a", { href }, job.input.name), h("span.muted.small", ` ${job.input.format}, ${formatBytes(job.input.size_bytes)}`)),
    h("td", { "data-label": "Stages" }, stageStrip(job),
      h("span.muted.small", ` ${done}/${job.stages.length} · ${Math.round(job.progress * 100)}%`)));
}

export function jobsCard() {
  const cursors = [null]; // cursor of each page visited; the last is the current page
  let next = null, timer = 0, inflight = null, status = "";
  const tbody = h("tbody");
  const note = h("p.muted.small.refresh-note", { "aria-live": "off" });
  const pageLabel = h("span.page-label");
  const prev = h("button", { type: "button", onclick: () => { cursors.pop(); load(); }, disabled: true }, "← Newer");
  const older = h("button", { type: "button", onclick: () => { cursors.push(next); load(); }, disabled: true }, "Older →");
  const filter = h("select#status-filter", { onchange: () => { status = filter.value; cursors.length = 1; load(); } },
    ["", "queued", "running", "succeeded", "failed", "canceled"].map((s) => h("option", { value: s }, s || "all")));
  const error = h("p.error-text", { role: "alert", hidden: true });
  const table = h("table.jobs", h("caption.visually-hidden", "Jobs, newest first"),
    h("thead", h("tr", ["Job", "Status", "Created", "Input", "Stages"].map((c) => h("th", { scope: "col" }, c)))), tbody);
  const card = h("section.card.jobs-card", { "aria-labelledby": "jobs-title" },
    h("div.card-head", h("h2#jobs-title", "Jobs"),
      h("div.filters", h("label", { for: "status-filter" }, "Status "), filter,
        h("button", { type: "button", onclick: () => load(), title: "Refresh now" }, "Refresh"))),
    error, h("div.table-wrap", table), h("nav.pager", { "aria-label": "Job pages" }, prev, pageLabel, older), note);

  async function load() {
    clearTimeout(timer);
    inflight?.abort();
    const ctrl = new AbortController();
    inflight = ctrl;
    try {
      const page = await api.listJobs({ limit: PAGE_SIZE, cursor: cursors[cursors.length - 1], status: status || undefined }, ctrl.signal);
      if (ctrl.signal.aborted) return;
      error.hidden = true;
      next = page.next_cursor;
      tbody.replaceChildren(...(page.items.length ? page.items.map(row)
        : [h("tr", h("td.empty", { colspan: "5" }, cursors.length > 1 ? "No more jobs."
          : status ? `No ${status} jobs.` : "No jobs yet: drop a point cloud or mesh on “New job” to start one."))]));
      prev.disabled = cursors.length <= 1;
      older.disabled = !next;
      pageLabel.textContent = `page ${cursors.length}`;
      note.textContent = `Updated ${new Date().toLocaleTimeString()}; refreshes every ${REFRESH_MS / 1000} s.`;
    } catch (err) {
      if (err.name === "AbortError") return;
      error.textContent = `Could not load the jobs: ${err.message}`;
      error.hidden = false;
    }
    if (inflight === ctrl && card.isConnected !== false) timer = setTimeout(tick, REFRESH_MS);
  }
  function tick() {
    if (!card.isConnected) return;
    if (document.hidden) { timer = setTimeout(tick, REFRESH_MS); return; }
    load();
  }
  load();
  card.destroy = () => { clearTimeout(timer); inflight?.abort(); };
  return card;
}
