// The REST API from the browser: JSON in and out, problem+json errors as ApiError, the optional API key.

const KEY_STORE = "cloud2cnc.apiKey";

export class ApiError extends Error {
  constructor(status, problem) {
    super(problem?.detail || problem?.title || `HTTP ${status}`);
    this.status = status;
    this.problem = problem || {};
    this.errors = Array.isArray(problem?.errors) ? problem.errors : [];
  }
}

let onUnauthorized = () => {};
export function setUnauthorizedHandler(fn) { onUnauthorized = fn; }

export function apiKey() {
  try { return sessionStorage.getItem(KEY_STORE) || ""; } catch { return ""; }
}
export function setApiKey(key) {
  try { key ? sessionStorage.setItem(KEY_STORE, key) : sessionStorage.removeItem(KEY_STORE); } catch { /* private mode */ }
}
export function authHeaders() {
  const key = apiKey();
  return key ? { "X-API-Key": key } : {};
}

async function problemOf(res) {
  const type = res.headers.get("content-type") || "";
  if (type.includes("json")) {
    try { return await res.json(); } catch { /* fall through */ }
  }
  return { title: res.statusText || "Error", detail: `the server answered ${res.status} ${res.statusText}` };
}

export async function request(method, url, { json, body, headers, signal } = {}) {
  const init = { method, headers: { Accept: "application/json", ...authHeaders(), ...(headers || {}) }, signal };
  if (json !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(json);
  } else if (body !== undefined) {
    init.body = body;
  }
  let res;
  try {
    res = await fetch(url, init);
  } catch (err) {
    if (err.name === "AbortError") throw err;
    throw new ApiError(0, { title: "Network error", detail: "the server cannot be reached; is cloud2cnc serve running?" });
  }
  if (res.status === 401) onUnauthorized();
  if (!res.ok) throw new ApiError(res.status, await problemOf(res));
  if (res.status === 204) return null;
  return res.json();
}

export const api = {
  listJobs: ({ limit = 20, cursor, status } = {}, signal) => {
    const q = new URLSearchParams({ limit: String(limit) });
    if (cursor) q.set("cursor", cursor);
    if (status) q.set("status", status);
    return request("GET", `/v1/jobs?${q}`, { signal });
  },
  getJob: (id, signal) => request("GET", `/v1/jobs/${encodeURIComponent(id)}`, { signal }),
  cancel: (id) => request("POST", `/v1/jobs/${encodeURIComponent(id)}/cancel`),
  rerun: (id, params) => request("POST", `/v1/jobs/${encodeURIComponent(id)}/rerun`, { json: { params } }),
  remove: (id) => request("DELETE", `/v1/jobs/${encodeURIComponent(id)}`),
  paramsSchema: () => request("GET", "/ui/params-schema.json"),
};

/** POST /v1/jobs as multipart with upload progress (fetch has none): resolves to the job body. */
export function createJob(file, params, { onProgress, idempotencyKey } = {}) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", "/v1/jobs");
    xhr.setRequestHeader("Accept", "application/json");
    for (const [k, v] of Object.entries(authHeaders())) xhr.setRequestHeader(k, v);
    if (idempotencyKey) xhr.setRequestHeader("Idempotency-Key", idempotencyKey);
    xhr.upload.onprogress = (e) => { if (e.lengthComputable && onProgress) onProgress(e.loaded / e.total); };
    xhr.onerror = () => reject(new ApiError(0, { title: "Network error", detail: "the upload did not reach the server" }));
    xhr.onload = () => {
      let body = null;
      try { body = JSON.parse(xhr.responseText); } catch { /* not JSON */ }
      if (xhr.status === 401) onUnauthorized();
      if (xhr.status >= 200 && xhr.status < 300) resolve(body);
      else reject(new ApiError(xhr.status, body || { title: "Error", detail: `the server answered ${xhr.status}` }));
    };
    const form = new FormData();
    form.append("file", file, file.name);
    form.append("params", JSON.stringify(params || {}));
    xhr.send(form);
  });
}

/**
 * Fetch an artifact as an ArrayBuffer, reporting progress (0..1, or null when the size is unknown).
 * Large files arrive in chunks; the page stays responsive while they do.
 */
export async function fetchArtifact(url, { onProgress, signal } = {}) {
  let res;
  try {
    res = await fetch(url, { headers: authHeaders(), signal });
  } catch (err) {
    if (err.name === "AbortError") throw err;
    throw new ApiError(0, { title: "Network error", detail: `could not download ${url}` });
  }
  if (res.status === 401) onUnauthorized();
  if (!res.ok) throw new ApiError(res.status, await problemOf(res));
  const total = Number(res.headers.get("content-length")) || 0;
  if (!res.body || !res.body.getReader) return res.arrayBuffer();
  const reader = res.body.getReader();
  const chunks = [];
  let got = 0;
  for (;;) {
    const { done, value } = await reader.read();
    if (done) break;
    chunks.push(value);
    got += value.byteLength;
    if (onProgress) onProgress(total ? got / total : null, got);
  }
  const out = new Uint8Array(got);
  let at = 0;
  for (const c of chunks) { out.set(c, at); at += c.byteLength; }
  return out.buffer;
}

/** Save an artifact through fetch (so the API key header goes along), as a download. */
export async function downloadWithKey(url, name) {
  const buf = await fetchArtifact(url);
  const href = URL.createObjectURL(new Blob([buf]));
  const a = document.createElement("a");
  a.href = href;
  a.download = name;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(href), 10000);
}
