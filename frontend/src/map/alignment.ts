// What the co-registration did to the post survey, in words the map states beside it: a
// flight on stand-alone GNSS can sit metres off the one before, and a map that draws both as
// uploaded shows the whole slope as if it had moved.

import { formatFixed } from "../format";
import { t } from "../i18n";

export interface Correction {
  shift_m?: { east?: number; north?: number; up?: number };
  rotation_deg?: number;
}

/** The value with `digits` decimals in the page's locale, a true minus sign, never "−0.00". */
function signed(value: number, digits: number): string {
  const text = formatFixed(Math.abs(value), digits);
  return value < 0 && Math.abs(value) >= 0.5 * 10 ** -digits ? `−${text}` : text;
}

const metres = (value: number) => t("unit.metres", { value: signed(value, 2) });

/** "post moved 2.10 m E, 0.40 m N, −7.50 m up and turned 0.02° to match pre"; null when the
 * comparison has no correction (not run yet). */
export function correctionText(summary: Correction | null | undefined): string | null {
  const shift = summary?.shift_m;
  if (!shift) return null;
  const rotation = summary?.rotation_deg ?? 0;
  const turned = Math.abs(rotation) >= 0.005 ? t("map.turned", { degrees: signed(rotation, 2) }) : "";
  return t("map.correction", {
    east: metres(shift.east ?? 0),
    north: metres(shift.north ?? 0),
    up: metres(shift.up ?? 0),
    turned,
  });
}
