// Swipe between the pre and post layers: each pane is clipped to its side of a divider
// that a range input moves (so the keyboard moves it too).

export interface Point {
  x: number;
  y: number;
}

/** CSS `clip` rectangles for the left and right panes, in the panes' own (layer) pixel
 * coordinates: `topLeft`/`bottomRight` are the map container's corners in those pixels. */
export function swipeClips(topLeft: Point, bottomRight: Point, fraction: number): { left: string; right: string } {
  const f = Math.max(0, Math.min(1, fraction));
  const x = topLeft.x + (bottomRight.x - topLeft.x) * f;
  const rect = (l: number, r: number) => `rect(${topLeft.y}px, ${r}px, ${bottomRight.y}px, ${l}px)`;
  return { left: rect(topLeft.x, x), right: rect(x, bottomRight.x) };
}

/** Which side of the divider an overlay (Δh, detections, …) is drawn on while swiping. */
export type SwipeSide = "both" | "left" | "right";

/** The CSS `clip` of an overlay's pane on `side` ("" draws it on both sides). */
export function sideClip(side: SwipeSide, clips: { left: string; right: string }): string {
  return side === "both" ? "" : clips[side];
}
