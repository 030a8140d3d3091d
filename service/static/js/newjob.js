// "New job": a file by drag-and-drop or the file picker, the parameter form, upload with progress.

import { ApiError, api, createJob } from "./api.js";
import { ParamsForm } from "./form.js";
import { formatBytes, h, progressBar } from "./util.js";

const ACCEPT = ".ply,.xyz,.pts,.txt,.csv,.pcd,.e57,.las,.laz,.obj,.stl";

let schemaPromise = null;
export function paramsSchema() {
  schemaPromise ||= api.paramsSchema().catch((err) => { schemaPromise = null; throw err; });
  return schemaPromise;
}

/** Show a problem+json error: field errors next to their fields, the rest in the summary box. */
export function showProblem(summary, form, err, fileError) {
  summary.textContent = "";
  summary.hidden = false;
  if (!(err instanceof ApiError)) {
    summary.append(h("strong", "Could not submit: "), err.message || String(err));
    return;
  }
  const fileErrs = err.errors.filter((e) => e.field === "file");
  if (fileError && fileErrs.length) {
    fileError.textContent = `${err.problem.title || "Invalid file"}: ${err.problem.detail || fileErrs[0].message}`;
    fileError.hidden = false;
  }
  const rest = form ? form.setErrors(err.errors.filter((e) => e.field !== "file")) : err.errors;
  const title = err.problem.title || `Error ${err.status}`;
  summary.append(h("strong", `${title}: `), err.problem.detail || err.message);
  if (rest.length && rest.length !== err.errors.length) {
    summary.append(h("ul", rest.map((e) => h("li", `${e.field}: ${e.message}`))));
  }
}

export function newJobCard({ focus = false } = {}) {
  let file = null;
  const fileInput = h("input#file-input", { type: "file", accept: ACCEPT, "aria-describedby": "file-hint file-error" });
  const fileName = h("p.file-name", { "aria-live": "polite" }, "No file chosen.");
  const fileError = h("p.field-error#file-error", { role: "alert", hidden: true });
  const drop = h("div.dropzone", { tabindex: "0", role: "button", "aria-controls": "file-input",
    "aria-label": "Choose a point cloud or mesh file, or drop one here" },
  h("strong", "Drop a point cloud or mesh here"), h("span", " or "),
  h("label.linklike", { for: "file-input" }, "choose a file"),
  h("p.hint#file-hint", "PLY, XYZ/PTS/TXT/CSV, PCD, E57, LAS/LAZ (clouds); OBJ, STL, PLY with faces (meshes). Read from the content, not the name."));

  const setFile = (f) => {
    file = f || null;
    fileError.hidden = true;
    fileName.textContent = file ? `${file.name} — ${formatBytes(file.size)}` : "No file chosen.";
    drop.classList.toggle("has-file", Boolean(file));
    submit.disabled = !file;
  };
  fileInput.addEventListener("change", () => setFile(fileInput.files[0]));
  drop.addEventListener("click", (e) => { if (e.target.tagName !== "LABEL") fileInput.click(); });
  drop.addEventListener("keydown", (e) => {
    if (e.key === "Enter" || e.key === " ") { e.preventDefault(); fileInput.click(); }
  });
  for (const ev of ["dragenter", "dragover"]) {
    drop.addEventListener(ev, (e) => { e.preventDefault(); drop.classList.add("dragging"); });
  }
  for (const ev of ["dragleave", "dragend"]) drop.addEventListener(ev, () => drop.classList.remove("dragging"));
  drop.addEventListener("drop", (e) => {
    e.preventDefault();
    drop.classList.remove("dragging");
    const f = e.dataTransfer?.files?.[0];
    if (f) setFile(f);
  });

  const paramsHolder = h("div.params-holder", h("p.muted", "Loading parameters…"));
  const summary = h("div.problem", { role: "alert", hidden: true });
  const upload = h("div.upload-progress", { hidden: true });
  const submit = h("button.primary", { type: "submit", disabled: true }, "Start job");
  const reset = h("button", { type: "button", onclick: () => params && build(params.defaults()) }, "Reset to defaults");
  let params = null;
  const form = h("form#new-job", { "aria-labelledby": "new-job-title" },
    drop, fileInput, fileName, fileError,
    h("h3", "Parameters"), paramsHolder, summary, upload, h("div.actions", submit, reset));

  const build = (values) => {
    paramsSchema().then((schema) => {
      params = new ParamsForm(schema, values, "new");
      paramsHolder.replaceChildren(params.el);
    }, (err) => {
      paramsHolder.replaceChildren(h("p.error-text", `The parameter form could not load: ${err.message}. Jobs start with the defaults.`));
    });
  };
  build({});

  let idemKey = null;
  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    if (!file) { fileError.textContent = "Choose a file first."; fileError.hidden = false; return; }
    summary.hidden = true;
    params?.clearErrors();
    if (params && !form.noValidate && !params.validate()) return;
    let values = {};
    try { values = params ? params.changes(params.defaults()) : {}; } catch (err) { showProblem(summary, params, err); return; }
    idemKey ||= crypto.randomUUID?.() || `${Date.now()}-${Math.random()}`;
    submit.disabled = true;
    upload.hidden = false;
    upload.replaceChildren(h("span", `Uploading ${file.name}…`), progressBar(0, { label: "upload" }));
    try {
      const job = await createJob(file, values, {
        idempotencyKey: idemKey,
        onProgress: (f) => upload.replaceChildren(h("span", `Uploading ${file.name}… ${Math.round(f * 100)}%`), progressBar(f, { label: "upload" })),
      });
      idemKey = null;
      location.hash = `#/jobs/${job.id}`;
    } catch (err) {
      if (err instanceof ApiError && err.status !== 0) idemKey = null; // answered: a new attempt is a new request
      upload.hidden = true;
      showProblem(summary, params, err, fileError);
    } finally {
      submit.disabled = !file;
    }
  });

  const card = h("section.card.new-job", { "aria-labelledby": "new-job-title" }, h("h2#new-job-title", "New job"), form);
  if (focus) setTimeout(() => drop.focus(), 0);
  return card;
}
