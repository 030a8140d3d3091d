// The parameter form, generated from the JSON schema of `JobParams` (served at /ui/params-schema.json).
// One fieldset per stage group; units come from the name suffix; bounds become constraint validation;
// the server's problem+json `errors[].field` ("params.tool.radius_mm") lands next to its input.

import { h } from "./util.js";

const UNITS = [
  [/_mm_per_min$/, "mm/min"], [/_mm2$/, "mm²"], [/_mm$/, "mm"], [/_deg$/, "°"], [/_s$/, "s"],
  [/_pct$/, "%"], [/_rpm$/, "rpm"],
];
const GROUP_TITLES = {
  ingest: "Ingest", reconstruct: "Reconstruct (IGR)", denoise: "Denoise (MeshTGV)", remesh: "Remesh (QuadriFlow)",
  segment: "Segment", fit: "Fit (B-splines)", tool: "Tool", toolpath: "Tool path",
};
// The groups a CAM engineer changes most are open by default.
const OPEN_GROUPS = new Set(["ingest", "tool", "toolpath"]);

function resolve(schema, node) {
  let n = node;
  for (let i = 0; n && n.$ref && i < 10; i++) {
    const path = n.$ref.replace(/^#\//, "").split("/");
    n = path.reduce((o, k) => (o ? o[k] : undefined), schema);
  }
  if (n && Array.isArray(n.allOf) && n.allOf.length === 1) return resolve(schema, { ...n.allOf[0], ...n, allOf: undefined });
  return n || {};
}

function unitOf(name) {
  for (const [re, unit] of UNITS) if (re.test(name)) return { unit, base: name.replace(re, "") };
  return { unit: "", base: name };
}

function labelOf(name) {
  const { base } = unitOf(name);
  const text = base.replace(/_/g, " ");
  return text.length <= 3 ? text.toUpperCase() : text[0].toUpperCase() + text.slice(1);
}

/** Field description: type (number|integer|boolean|enum|const|string|json), bounds, default. */
function describe(schema, prop) {
  let p = resolve(schema, prop);
  let nullable = false;
  if (Array.isArray(p.anyOf)) {
    const parts = p.anyOf.map((x) => resolve(schema, x));
    nullable = parts.some((x) => x.type === "null");
    const rest = parts.filter((x) => x.type !== "null");
    if (rest.length === 1) p = { ...rest[0], ...p, anyOf: undefined };
  }
  const d = { nullable, description: p.description || "", default: p.default, title: p.title };
  if (p.const !== undefined) return { ...d, kind: "const", value: p.const };
  if (Array.isArray(p.enum)) return { ...d, kind: p.enum.length === 1 ? "const" : "enum", options: p.enum, value: p.enum[0] };
  if (p.type === "number" || p.type === "integer") {
    return { ...d, kind: p.type, minimum: p.minimum, maximum: p.maximum,
      exclusiveMinimum: p.exclusiveMinimum, exclusiveMaximum: p.exclusiveMaximum };
  }
  if (p.type === "boolean") return { ...d, kind: "boolean" };
  if (p.type === "string") return { ...d, kind: "string", minLength: p.minLength, maxLength: p.maxLength, pattern: p.pattern };
  return { ...d, kind: "json" };
}

function boundsText(f) {
  const parts = [];
  if (f.minimum !== undefined) parts.push(`≥ ${f.minimum}`);
  if (f.exclusiveMinimum !== undefined) parts.push(`> ${f.exclusiveMinimum}`);
  if (f.maximum !== undefined) parts.push(`≤ ${f.maximum}`);
  if (f.exclusiveMaximum !== undefined) parts.push(`< ${f.exclusiveMaximum}`);
  return parts.join(", ");
}

/** Check one number input against the schema bounds; sets the browser's custom validity message. */
function checkNumber(input, f) {
  input.setCustomValidity("");
  if (input.value.trim() === "") {
    if (!f.nullable) input.setCustomValidity("enter a value");
    return;
  }
  const v = Number(input.value);
  let msg = "";
  if (!Number.isFinite(v)) msg = "enter a number";
  else if (f.kind === "integer" && !Number.isInteger(v)) msg = "enter a whole number";
  else if (f.minimum !== undefined && v < f.minimum) msg = `must be ≥ ${f.minimum}`;
  else if (f.exclusiveMinimum !== undefined && v <= f.exclusiveMinimum) msg = `must be > ${f.exclusiveMinimum}`;
  else if (f.maximum !== undefined && v > f.maximum) msg = `must be ≤ ${f.maximum}`;
  else if (f.exclusiveMaximum !== undefined && v >= f.exclusiveMaximum) msg = `must be < ${f.exclusiveMaximum}`;
  input.setCustomValidity(msg);
}

export class ParamsForm {
  /**
   * @param schema the JobParams JSON schema
   * @param values effective parameters to prefill (a job's `params` for a rerun); defaults otherwise
   * @param idPrefix keeps element ids unique when two forms are on one page
   */
  constructor(schema, values = {}, idPrefix = "p") {
    this.schema = schema;
    this.fields = new Map(); // "tool.radius_mm" -> {input, error, f, group, name}
    this.idPrefix = idPrefix;
    this.el = h("div.params");
    for (const [group, gprop] of Object.entries(schema.properties || {})) {
      const gschema = resolve(schema, gprop);
      const props = gschema.properties || {};
      const names = Object.keys(props);
      const fs = h("details.group", { open: OPEN_GROUPS.has(group), dataset: { group } });
      fs.append(h("summary", GROUP_TITLES[group] || labelOf(group),
        names.length ? null : h("span.muted", " — no parameters yet")));
      const grid = h("div.fields");
      for (const name of names) {
        const f = describe(schema, props[name]);
        const current = values?.[group]?.[name];
        grid.append(this._field(group, name, f, current !== undefined ? current : f.default));
      }
      if (gschema.description && !names.length) grid.append(h("p.muted", gschema.description));
      fs.append(grid);
      this.el.append(fs);
    }
  }

  _field(group, name, f, value) {
    const key = `${group}.${name}`;
    const id = `${this.idPrefix}-${group}-${name}`;
    const { unit } = unitOf(name);
    const errId = `${id}-err`;
    const hintId = `${id}-hint`;
    let input;
    const describedBy = `${hintId} ${errId}`;
    if (f.kind === "boolean") {
      input = h("input", { type: "checkbox", id, checked: Boolean(value), "aria-describedby": describedBy });
    } else if (f.kind === "enum" || f.kind === "const") {
      input = h("select", { id, "aria-describedby": describedBy, disabled: f.kind === "const" },
        (f.options || [f.value]).map((o) => h("option", { value: String(o), selected: o === value }, String(o))));
    } else if (f.kind === "number" || f.kind === "integer") {
      input = h("input", { type: "number", id, inputmode: f.kind === "integer" ? "numeric" : "decimal",
        step: f.kind === "integer" ? "1" : "any", value: value === null || value === undefined ? "" : String(value),
        "aria-describedby": describedBy });
      if (f.minimum !== undefined) input.min = String(f.minimum);
      if (f.maximum !== undefined) input.max = String(f.maximum);
      const check = () => checkNumber(input, f);
      input.addEventListener("input", () => { check(); this._showClient(key); });
      check();
    } else if (f.kind === "string") {
      input = h("input", { type: "text", id, value: value ?? "", "aria-describedby": describedBy });
      if (f.maxLength) input.maxLength = f.maxLength;
    } else {
      input = h("textarea", { id, rows: "2", "aria-describedby": describedBy, spellcheck: "false" },
        value === undefined ? "" : JSON.stringify(value));
    }
    input.name = key;
    input.dataset.field = `params.${key}`;
    const hint = [f.description, boundsText(f)].filter(Boolean).join(" ");
    const error = h("p.field-error", { id: errId, role: "alert", "aria-live": "polite", hidden: true });
    const row = h(`div.field.kind-${f.kind}`, { dataset: { field: `params.${key}` } },
      h("label", { for: id }, labelOf(name), unit && f.kind === "boolean" ? h("span.unit", ` (${unit})`) : null),
      h("div.control", input, unit && f.kind !== "boolean" ? h("span.unit-suffix", { "aria-hidden": "true" }, unit) : null),
      hint ? h("p.hint", { id: hintId }, hint) : h("span", { id: hintId, hidden: true }),
      error);
    this.fields.set(key, { input, error, f, group, name, row });
    return row;
  }

  _showClient(key) {
    const { input, error, row } = this.fields.get(key);
    const msg = input.validationMessage;
    error.textContent = msg;
    error.hidden = !msg;
    row.classList.toggle("invalid", Boolean(msg));
    input.setAttribute("aria-invalid", msg ? "true" : "false");
  }

  /** The parameters as the API takes them, grouped. Throws on a JSON field that does not parse. */
  values() {
    const out = {};
    for (const [key, { input, f, group, name }] of this.fields) {
      let v;
      if (f.kind === "boolean") v = input.checked;
      else if (f.kind === "number" || f.kind === "integer") v = input.value.trim() === "" ? null : Number(input.value);
      else if (f.kind === "enum" || f.kind === "const") {
        const opt = (f.options || [f.value]).find((o) => String(o) === input.value);
        v = opt === undefined ? input.value : opt;
      } else if (f.kind === "string") v = input.value;
      else {
        try { v = input.value.trim() ? JSON.parse(input.value) : undefined; } catch {
          this.setErrors([{ field: `params.${key}`, message: "not valid JSON" }]);
          throw new Error(`${key} is not valid JSON`);
        }
      }
      if (v === undefined) continue;
      if (typeof v === "number" && !Number.isFinite(v)) v = input.value; // let the server say what is wrong
      (out[group] ||= {})[name] = v;
    }
    return out;
  }

  /** Only what differs from `base` (a job's effective params, or the defaults), for compact requests. */
  changes(base) {
    const out = {};
    const vals = this.values();
    for (const [group, fields] of Object.entries(vals)) {
      for (const [name, v] of Object.entries(fields)) {
        const b = base?.[group]?.[name];
        if (JSON.stringify(b) !== JSON.stringify(v)) (out[group] ||= {})[name] = v;
      }
    }
    return out;
  }

  defaults() {
    const out = {};
    for (const [, { f, group, name }] of this.fields) if (f.default !== undefined) (out[group] ||= {})[name] = f.default;
    return out;
  }

  /** Client-side check of every field (unless the surrounding form has novalidate). */
  validate() {
    let first = null;
    for (const [key, { input }] of this.fields) {
      this._showClient(key);
      if (!input.checkValidity() && !first) first = input;
    }
    if (first) {
      first.closest("details")?.setAttribute("open", "");
      first.focus();
    }
    return !first;
  }

  clearErrors() {
    for (const [, { error, row, input }] of this.fields) {
      error.textContent = "";
      error.hidden = true;
      row.classList.remove("invalid");
      input.removeAttribute("aria-invalid");
    }
  }

  /**
   * Show the server's problem+json `errors` next to their fields; returns the errors that matched no field
   * (the caller shows those in the form's summary).
   */
  setErrors(errors) {
    const unmatched = [];
    let first = null;
    for (const e of errors || []) {
      const key = String(e.field || "").replace(/^params\./, "");
      const entry = this.fields.get(key);
      if (!entry) { unmatched.push(e); continue; }
      entry.error.textContent = e.message;
      entry.error.hidden = false;
      entry.row.classList.add("invalid");
      entry.input.setAttribute("aria-invalid", "true");
      if (!first) first = entry;
    }
    if (first) {
      first.row.closest("details")?.setAttribute("open", "");
      first.input.focus();
    }
    return unmatched;
  }
}
