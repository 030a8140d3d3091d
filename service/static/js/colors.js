// Colours: a patch palette that keeps neighbours apart, and the heat-map scale with its CSS gradient.

export const BASE_COLOR = [0.55, 0.57, 0.6];       // the setup base (patches.json base_faces)
export const UNASSIGNED_COLOR = [0.25, 0.25, 0.28]; // faces in no patch
export const UNREACHED_COLOR = [0.42, 0.42, 0.46]; // scallop.ply: NaN / negative = no setup reaches it

function hsl(h, s, l) {
  const a = s * Math.min(l, 1 - l);
  const f = (n) => {
    const k = (n + h * 12) % 12;
    return l - a * Math.max(-1, Math.min(k - 3, 9 - k, 1));
  };
  return [f(0), f(8), f(4)];
}

/** Colour of patch `id` (0..1 RGB): golden-angle hues, alternating lightness. */
export function patchColor(id) {
  if (!Number.isInteger(id) || id < 0) return UNASSIGNED_COLOR;
  const hue = (id * 0.618033988749895 + 0.08) % 1;
  return hsl(hue, 0.62, id % 2 ? 0.48 : 0.6);
}

export function patchCss(id) {
  const [r, g, b] = patchColor(id);
  return `rgb(${Math.round(r * 255)} ${Math.round(g * 255)} ${Math.round(b * 255)})`;
}

// A perceptual blue → red ramp (close to matplotlib's "turbo", sampled).
const HEAT = [
  [0.19, 0.07, 0.23], [0.27, 0.35, 0.82], [0.16, 0.64, 0.98], [0.1, 0.88, 0.72], [0.45, 0.99, 0.37],
  [0.8, 0.92, 0.2], [0.99, 0.68, 0.14], [0.93, 0.33, 0.06], [0.64, 0.08, 0.01],
];

export function heatColor(t) {
  const x = Math.max(0, Math.min(1, Number.isFinite(t) ? t : 0)) * (HEAT.length - 1);
  const i = Math.min(HEAT.length - 2, Math.floor(x)), f = x - i;
  const a = HEAT[i], b = HEAT[i + 1];
  return [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f];
}

export function heatGradientCss() {
  const stops = HEAT.map((c, i) => `rgb(${c.map((v) => Math.round(v * 255)).join(" ")}) ${(100 * i / (HEAT.length - 1)).toFixed(1)}%`);
  return `linear-gradient(to right, ${stops.join(", ")})`;
}
