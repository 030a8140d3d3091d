// Web Worker: parse artifacts off the main thread so a large file never freezes the page.
import { decimateGeometry, objGeometry, parseGcode, plyGeometry, surfacesGeometry } from "./parsers.js";

export function runTask(task, payload, options = {}) {
  switch (task) {
    case "ply": {
      let geo = plyGeometry(payload, options);
      if (!geo.tris && options.pointBudget) geo = decimateGeometry(geo, options.pointBudget);
      return geo;
    }
    case "obj": return objGeometry(new TextDecoder().decode(payload), options);
    case "gcode": return parseGcode(new TextDecoder().decode(payload));
    case "surfaces": return surfacesGeometry(JSON.parse(new TextDecoder().decode(payload)), options.res);
    default: throw new Error(`unknown task ${task}`);
  }
}

function transferables(obj, out = new Set()) {
  if (!obj || typeof obj !== "object") return out;
  if (ArrayBuffer.isView(obj)) { out.add(obj.buffer); return out; }
  for (const v of Object.values(obj)) transferables(v, out);
  return out;
}

if (typeof self !== "undefined" && typeof window === "undefined") {
  self.onmessage = (e) => {
    const { id, task, payload, options } = e.data;
    try {
      const result = runTask(task, payload, options);
      self.postMessage({ id, result }, [...transferables(result)]);
    } catch (err) {
      self.postMessage({ id, error: err?.message || String(err) });
    }
  };
}
