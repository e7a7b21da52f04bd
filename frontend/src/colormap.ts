// Legends that match the tiles: the same colormaps (sampled from rio-tiler's, which render
// the tiles) over the same stretch, with ticks in metres.

export const COLORMAPS: Record<string, string[]> = {
  // 11 evenly spaced stops of rio-tiler's `terrain` and `rdbu_r`.
  terrain: ["#333399", "#1175db", "#00b2b2", "#31d56f", "#99ea84", "#fdfe98", "#ccbd7d", "#9a7d62", "#997c76", "#cbbcb9", "#ffffff"],
  rdbu_r: ["#053061", "#2064aa", "#4393c3", "#90c4dd", "#d1e5f0", "#f6f6f6", "#fddbc7", "#f4a683", "#d6604d", "#b2192b", "#67001f"],
};

export function cssGradient(name: string, direction = "to right"): string {
  const stops = COLORMAPS[name];
  if (!stops) throw new Error(`unknown colormap ${name}`);
  return `linear-gradient(${direction}, ${stops.join(", ")})`;
}

/** One stretch for both DSMs of a comparison, so that a colour means one elevation. */
export function unionRange(ranges: Array<[number, number] | null | undefined>): [number, number] | null {
  const known = ranges.filter((r): r is [number, number] => !!r);
  if (!known.length) return null;
  return [Math.min(...known.map((r) => r[0])), Math.max(...known.map((r) => r[1]))];
}

/** A diverging stretch centred on zero: no change is the colormap's middle. */
export function symmetricRange(range: [number, number] | null | undefined): [number, number] {
  const extent = range ? Math.max(Math.abs(range[0]), Math.abs(range[1])) : 1;
  const rounded = niceCeil(Math.max(extent, 0.01));
  return [-rounded, rounded];
}

function niceCeil(value: number): number {
  const power = 10 ** Math.floor(Math.log10(value));
  for (const step of [1, 2, 2.5, 5, 10]) {
    if (value <= step * power + 1e-9) return step * power;
  }
  return 10 * power;
}

/** About `count` round tick values between low and high (inclusive where round). */
export function ticks(low: number, high: number, count = 5): number[] {
  if (!(high > low)) return [low];
  const raw = (high - low) / Math.max(1, count - 1);
  const step = niceCeil(raw);
  const first = Math.ceil(low / step - 1e-9) * step;
  const values: number[] = [];
  for (let v = first; v <= high + step * 1e-6; v += step) values.push(Number(v.toFixed(6)));
  return values;
}

/** Position (0..1) of `value` along a legend for [low, high]. */
export function legendPosition(value: number, low: number, high: number): number {
  return Math.max(0, Math.min(1, (value - low) / (high - low)));
}

export function rescaleParam(range: [number, number]): string {
  return `${range[0].toFixed(3)},${range[1].toFixed(3)}`;
}
