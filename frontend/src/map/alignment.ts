// What the co-registration did to the post survey, in words the map states beside it: a
// flight on stand-alone GNSS can sit metres off the one before, and a map that draws both as
// uploaded shows the whole slope as if it had moved.

export interface Correction {
  shift_m?: { east?: number; north?: number; up?: number };
  rotation_deg?: number;
}

function signed(value: number, digits: number): string {
  const text = Math.abs(value).toFixed(digits);
  return value < 0 && Number(text) !== 0 ? `−${text}` : text;
}

/** "post moved 2.10 m E, 0.40 m N, −7.50 m up and turned 0.02° to match pre"; null when the
 * comparison has no correction (not run yet). */
export function correctionText(summary: Correction | null | undefined): string | null {
  const shift = summary?.shift_m;
  if (!shift) return null;
  const parts = [
    `${signed(shift.east ?? 0, 2)} m E`,
    `${signed(shift.north ?? 0, 2)} m N`,
    `${signed(shift.up ?? 0, 2)} m up`,
  ];
  const rotation = summary?.rotation_deg ?? 0;
  const turned = Math.abs(rotation) >= 0.005 ? ` and turned ${signed(rotation, 2)}°` : "";
  return `post moved ${parts.join(", ")}${turned} to match pre`;
}
