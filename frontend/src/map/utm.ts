// Latitude/longitude (WGS84) to UTM, for the cursor readout and positions a field team walks
// to. Krüger's series to n^4 (as in Karney 2011, eq. 35): below a millimetre within the zone,
// which is all a readout needs; the server's products keep their own CRS.

const A = 6378137.0;
const F = 1 / 298.257223563;
const K0 = 0.9996;
const N = F / (2 - F);
const A_RECT = (A / (1 + N)) * (1 + N ** 2 / 4 + N ** 4 / 64);
const ALPHA = [
  N / 2 - (2 / 3) * N ** 2 + (5 / 16) * N ** 3 + (41 / 180) * N ** 4,
  (13 / 48) * N ** 2 - (3 / 5) * N ** 3 + (557 / 1440) * N ** 4,
  (61 / 240) * N ** 3 - (103 / 140) * N ** 4,
  (49561 / 161280) * N ** 4,
];

export interface Utm {
  zone: number;
  hemisphere: "N" | "S";
  easting: number;
  northing: number;
}

/** The standard UTM zone of a longitude (1..60); Norway's and Svalbard's exceptions aside. */
export function utmZone(lon: number): number {
  return Math.min(60, Math.max(1, Math.floor((lon + 180) / 6) + 1));
}

export function toUtm(lat: number, lon: number, zone: number = utmZone(lon)): Utm {
  const phi = (lat * Math.PI) / 180;
  const lambda = ((lon - (zone * 6 - 183)) * Math.PI) / 180;
  const e = Math.sqrt(F * (2 - F));
  const t = Math.sinh(Math.atanh(Math.sin(phi)) - e * Math.atanh(e * Math.sin(phi)));
  const xi0 = Math.atan2(t, Math.cos(lambda));
  const eta0 = Math.atanh(Math.sin(lambda) / Math.sqrt(1 + t * t));
  let xi = xi0;
  let eta = eta0;
  ALPHA.forEach((a, i) => {
    const j = 2 * (i + 1);
    xi += a * Math.sin(j * xi0) * Math.cosh(j * eta0);
    eta += a * Math.cos(j * xi0) * Math.sinh(j * eta0);
  });
  const easting = 500000 + K0 * A_RECT * eta;
  const north = K0 * A_RECT * xi;
  return { zone, hemisphere: lat >= 0 ? "N" : "S", easting, northing: lat >= 0 ? north : north + 10000000 };
}

/** "54N 419350.2 E 3990820.7 N" */
export function formatUtm(utm: Utm): string {
  return `${utm.zone}${utm.hemisphere} ${utm.easting.toFixed(1)} E ${utm.northing.toFixed(1)} N`;
}

/** "35.012345° N, 135.678901° E": six decimals are about 10 cm. */
export function formatLatLon(lat: number, lon: number): string {
  return `${Math.abs(lat).toFixed(6)}° ${lat >= 0 ? "N" : "S"}, ${Math.abs(lon).toFixed(6)}° ${lon >= 0 ? "E" : "W"}`;
}
