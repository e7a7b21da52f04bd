// Where a popup may sit on the map: clear of the map's own controls (zoom, layers, measure,
// legend, scale, the swipe slider) and of the part of the map outside the browser's window.
// On a phone these cover a good share of a short map, and Leaflet's autopan alone only
// keeps a popup inside the map's box.

import L from "leaflet";

export interface Box {
  left: number;
  top: number;
  right: number;
  bottom: number;
}

export interface Clearance {
  /** Leaflet's autoPanPaddingTopLeft and autoPanPaddingBottomRight, in map pixels. */
  topLeft: [number, number];
  bottomRight: [number, number];
  /** The most the popup's content may take in height before it scrolls. */
  maxHeight: number;
}

const MARGIN = 8;
// Height of a popup beyond its content: its tip and margin below (40 px in Leaflet's CSS)
// and the content's wrapper padding.
const POPUP_CHROME = 64;
const MIN_CONTENT = 120;

/** Padding that keeps a popup clear of `obstacles` (boxes in the page, e.g. the controls)
 * within the part of `map` inside `view` (the window). An obstacle in the upper half of
 * the map pushes the popup's top below it, one in the lower half its bottom above it; one
 * taller than half the map (an unfolded panel) is left out, or nothing would remain, and
 * so is one beside the popup's columns (`span`, where given: left and right in the page). */
export function popupClearance(map: Box, view: Box, obstacles: Box[], span?: { left: number; right: number }): Clearance {
  const height = map.bottom - map.top;
  const middle = map.top + height / 2;
  let top = Math.max(0, view.top - map.top);
  let bottom = Math.max(0, map.bottom - view.bottom);
  for (const box of obstacles) {
    const overlaps = box.right > map.left && box.left < map.right && box.bottom > map.top && box.top < map.bottom;
    const beside = span !== undefined && (box.right <= span.left || box.left >= span.right);
    if (!overlaps || beside || box.bottom - box.top > height / 2) continue;
    if ((box.top + box.bottom) / 2 < middle) top = Math.max(top, box.bottom - map.top);
    else bottom = Math.max(bottom, map.bottom - box.top);
  }
  const left = Math.max(0, view.left - map.left);
  const right = Math.max(0, map.right - view.right);
  const free = height - top - bottom - 2 * MARGIN;
  return {
    topLeft: [left + MARGIN, top + MARGIN],
    bottomRight: [right + MARGIN, bottom + MARGIN],
    maxHeight: Math.max(MIN_CONTENT, Math.floor(free - POPUP_CHROME)),
  };
}

function boxOf(element: Element): Box {
  const { left, top, right, bottom } = element.getBoundingClientRect();
  return { left, top, right, bottom };
}

interface PopupInternals {
  _map?: L.Map;
  _latlng?: L.LatLng;
  _containerWidth?: number;
  _updateLayout(): void;
}

const popupLayout = (L.Popup.prototype as unknown as PopupInternals)._updateLayout;

/** A popup that, each time it is laid out, keeps clear of the map's controls and of the
 * part of the map outside the window (a phone's short map has little room between them):
 * its height is capped to the room left and the map pans to show it there. Only controls
 * above or below the popup's columns count: a laptop's legend beside it takes no room. */
const ClearPopup = L.Popup.extend({
  _updateLayout(this: L.Popup & PopupInternals) {
    popupLayout.call(this); // its width, for the columns it will take
    const map = this._map;
    if (!map || !this._latlng) return;
    const container = map.getContainer();
    const mapBox = boxOf(container);
    const width = this._containerWidth ?? 0;
    // Centred over its anchor, moved in from the map's sides as Leaflet's pan does.
    const anchor = map.latLngToContainerPoint(this._latlng).x;
    const left = mapBox.left + Math.max(0, Math.min(anchor - width / 2, mapBox.right - mapBox.left - width));
    const obstacles = [
      ...container.querySelectorAll(".leaflet-control"),
      ...container.querySelectorAll(".swipe:not([hidden]) .swipe-input, .swipe:not([hidden]) .swipe-tag"),
    ]
      .filter((element) => (element as HTMLElement).offsetParent !== null)
      .map(boxOf);
    const view = { left: 0, top: 0, right: window.innerWidth, bottom: window.innerHeight };
    const clearance = popupClearance(mapBox, view, obstacles, { left, right: left + width });
    const again = clearance.maxHeight !== this.options.maxHeight;
    L.Util.setOptions(this, {
      autoPanPaddingTopLeft: clearance.topLeft,
      autoPanPaddingBottomRight: clearance.bottomRight,
      maxHeight: clearance.maxHeight,
    });
    if (again) popupLayout.call(this); // capped to the room left
  },
});

/** A popup kept clear of the map's controls (see ClearPopup). */
export function clearPopup(options: L.PopupOptions): L.Popup {
  return new (ClearPopup as unknown as typeof L.Popup)(options);
}
