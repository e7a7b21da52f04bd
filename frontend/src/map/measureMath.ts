// The arithmetic of the map's measuring tools, apart from Leaflet so it can be tested:
// lengths and areas on the ground, and the elevation profile drawn as an SVG chart.

import { formatFixed } from "../format";
import { t } from "../i18n";

const EARTH_RADIUS_M = 6371008.8; // mean radius: lengths within 0.5 % anywhere

export type LonLat = [number, number];

/** Great-circle length of a path (haversine), in metres. */
export function pathLength(points: LonLat[]): number {
  let total = 0;
  for (let i = 1; i < points.length; i++) total += haversine(points[i - 1], points[i]);
  return total;
}

function haversine([lon1, lat1]: LonLat, [lon2, lat2]: LonLat): number {
  const rad = Math.PI / 180;
  const dLat = (lat2 - lat1) * rad;
  const dLon = (lon2 - lon1) * rad;
  const a = Math.sin(dLat / 2) ** 2 + Math.cos(lat1 * rad) * Math.cos(lat2 * rad) * Math.sin(dLon / 2) ** 2;
  return 2 * EARTH_RADIUS_M * Math.asin(Math.min(1, Math.sqrt(a)));
}

/** Area of a simple polygon (open ring), in m²: the ring projected onto a plane tangent at
 * its centre, which for a slope's few hundred metres is exact to far below a square metre. */
export function polygonArea(ring: LonLat[]): number {
  if (ring.length < 3) return 0;
  const lat0 = ring.reduce((s, p) => s + p[1], 0) / ring.length;
  const lon0 = ring.reduce((s, p) => s + p[0], 0) / ring.length;
  const rad = Math.PI / 180;
  const xy = ring.map(([lon, lat]) => [
    (lon - lon0) * rad * EARTH_RADIUS_M * Math.cos(lat0 * rad),
    (lat - lat0) * rad * EARTH_RADIUS_M,
  ]);
  let twice = 0;
  for (let i = 0; i < xy.length; i++) {
    const [x1, y1] = xy[i];
    const [x2, y2] = xy[(i + 1) % xy.length];
    twice += x1 * y2 - x2 * y1;
  }
  return Math.abs(twice) / 2;
}

export interface ProfileData {
  distance_m: number[];
  heights_m: Record<string, Array<number | null>>;
  length_m: number;
}

const SERIES_COLOURS: Record<string, string> = { pre: "#2563eb", post: "#dc2626", dsm: "#374151" };

/** Metres with one decimal, as the chart's axes write them. */
const metres = (value: number) => t("unit.metres", { value: formatFixed(value, 1) });

/** The profile as an SVG line chart (one line per DSM, gaps where it has no height), with
 * its height range and length written on it. */
export function profileSvg(profile: ProfileData, width = 300, height = 140): string {
  const pad = { left: 44, right: 8, top: 8, bottom: 22 };
  const values = Object.values(profile.heights_m).flat().filter((v): v is number => v != null);
  if (!values.length) return `<p>${t("measure.noHeight")}</p>`;
  let low = Math.min(...values);
  let high = Math.max(...values);
  if (high - low < 0.5) [low, high] = [(low + high) / 2 - 0.25, (low + high) / 2 + 0.25];
  const length = profile.length_m || 1;
  const x = (d: number) => pad.left + (d / length) * (width - pad.left - pad.right);
  const y = (h: number) => pad.top + ((high - h) / (high - low)) * (height - pad.top - pad.bottom);
  const lines = Object.entries(profile.heights_m).map(([name, heights]) => {
    let path = "";
    let pen = false;
    heights.forEach((h, i) => {
      if (h == null) {
        pen = false;
        return;
      }
      path += `${pen ? "L" : "M"}${x(profile.distance_m[i]).toFixed(1)},${y(h).toFixed(1)}`;
      pen = true;
    });
    return `<path d="${path}" fill="none" stroke="${SERIES_COLOURS[name] ?? "#111"}" stroke-width="1.5"><title>${name}</title></path>`;
  });
  const legend = Object.keys(profile.heights_m)
    .map((name, i) => `<text x="${pad.left + 6 + i * 44}" y="${pad.top + 10}" fill="${SERIES_COLOURS[name] ?? "#111"}" font-size="10">${name}</text>`)
    .join("");
  return `<svg class="profile-chart" viewBox="0 0 ${width} ${height}" width="${width}" height="${height}" role="img" aria-label="${t("measure.chart", { length: metres(profile.length_m) })}">
    <rect x="${pad.left}" y="${pad.top}" width="${width - pad.left - pad.right}" height="${height - pad.top - pad.bottom}" fill="#f8fafc" stroke="#cbd5e1"/>
    ${lines.join("")}${legend}
    <text x="${pad.left - 4}" y="${pad.top + 8}" text-anchor="end" font-size="10">${metres(high)}</text>
    <text x="${pad.left - 4}" y="${height - pad.bottom}" text-anchor="end" font-size="10">${metres(low)}</text>
    <text x="${pad.left}" y="${height - 6}" font-size="10">0</text>
    <text x="${width - pad.right}" y="${height - 6}" text-anchor="end" font-size="10">${metres(profile.length_m)}</text>
  </svg>`;
}
