// The map's measuring tools: distance and area drawn on the map, an elevation profile along
// a line (pre and post DSMs of the comparison shown, or the survey's), and the volume
// between pre and post inside a polygon (cut, fill, net and the part beyond the LoD).
// Click to add points; double-click or "Finish" to end, Escape or "Cancel" to stop.

import L from "leaflet";
import { ApiError, postJson } from "../api";
import { escapeHtml, formatArea, formatMetres, formatVolume, percent } from "../format";
import { type MessageKey, t } from "../i18n";
import { type LonLat, pathLength, polygonArea, type ProfileData, profileSvg } from "./measureMath";

export type MeasureKind = "distance" | "area" | "profile" | "volume";

/** What the measurements are made on: the site, and the comparison or survey shown. */
export interface MeasureContext {
  siteId: number;
  comparisonId: number | null;
  surveyId: number | null;
}

interface VolumeAnswer {
  area_m2: number;
  measured_m2: number;
  cut_m3: number;
  fill_m3: number;
  net_m3: number;
  cut_beyond_lod_m3: number;
  fill_beyond_lod_m3: number;
  lod_m: number | null;
}

const LINE_KINDS: MeasureKind[] = ["distance", "profile"];
const TITLES: Record<MeasureKind, MessageKey> = {
  distance: "measure.distance",
  area: "measure.area",
  profile: "measure.profile",
  volume: "measure.volume",
};

export class MeasureTool {
  private readonly box: HTMLElement;
  private readonly result: HTMLElement;
  private readonly drawn = L.layerGroup();
  private kind: MeasureKind | null = null;
  private points: L.LatLng[] = [];
  private shape: L.Path | null = null;

  constructor(
    private readonly map: L.Map,
    private readonly context: () => MeasureContext | null,
  ) {
    this.drawn.addTo(map);
    this.box = L.DomUtil.create("div", "leaflet-bar map-measure");
    L.DomEvent.disableClickPropagation(this.box);
    L.DomEvent.disableScrollPropagation(this.box);
    this.box.innerHTML = `<details><summary>${t("measure.measure")}</summary>
      <div class="measure-buttons">${(Object.keys(TITLES) as MeasureKind[])
        .map((k) => `<button type="button" data-measure="${k}">${t(TITLES[k])}</button>`)
        .join("")}</div>
      <div class="measure-drawing" hidden><span data-role="hint"></span>
        <button type="button" data-action="finish">${t("measure.finish")}</button><button type="button" data-action="cancel">${t("measure.cancel")}</button></div>
      <div class="measure-result" aria-live="polite"></div></details>`;
    this.result = this.box.querySelector(".measure-result") as HTMLElement;
    const control = new L.Control({ position: "topleft" });
    control.onAdd = () => this.box;
    control.addTo(map);
    this.box.querySelectorAll<HTMLButtonElement>("button[data-measure]").forEach((button) =>
      button.addEventListener("click", () => this.start(button.dataset.measure as MeasureKind)),
    );
    (this.box.querySelector("[data-action=finish]") as HTMLButtonElement).addEventListener("click", () => void this.finish());
    (this.box.querySelector("[data-action=cancel]") as HTMLButtonElement).addEventListener("click", () => this.stop());
    map.on("click", (event: L.LeafletMouseEvent) => this.add(event.latlng));
    map.on("dblclick", () => void this.finish());
    map.getContainer().addEventListener("keydown", (event) => {
      if (event.key === "Escape" && this.kind) this.stop();
    });
  }

  /** Start drawing the geometry of a measurement. */
  start(kind: MeasureKind): void {
    this.stop();
    this.kind = kind;
    this.drawn.clearLayers();
    this.result.innerHTML = "";
    this.map.doubleClickZoom.disable(); // a double-click ends the drawing
    this.map.getContainer().classList.add("measuring");
    const drawing = this.box.querySelector(".measure-drawing") as HTMLElement;
    drawing.hidden = false;
    (drawing.querySelector("[data-role=hint]") as HTMLElement).textContent = LINE_KINDS.includes(kind)
      ? t("measure.lineHint")
      : t("measure.areaHint");
  }

  /** Add a point (a click on the map, or a caller that knows where). */
  add(at: L.LatLng): void {
    if (!this.kind) return;
    // A double-click also sends two clicks: the second at the same place adds nothing.
    const last = this.points[this.points.length - 1];
    if (last && this.map.latLngToContainerPoint(last).distanceTo(this.map.latLngToContainerPoint(at)) < 3) return;
    this.points.push(at);
    this.shape?.remove();
    const style = { color: "#f59e0b", weight: 3, dashArray: "4 4", interactive: false };
    const shape = LINE_KINDS.includes(this.kind) || this.points.length < 3 ? L.polyline(this.points, style) : L.polygon(this.points, style);
    this.shape = shape;
    this.drawn.addLayer(shape);
  }

  private stop(): void {
    this.kind = null;
    this.points = [];
    this.shape = null;
    this.map.doubleClickZoom.enable();
    this.map.getContainer().classList.remove("measuring");
    (this.box.querySelector(".measure-drawing") as HTMLElement).hidden = true;
  }

  /** End the drawing and measure. */
  async finish(): Promise<void> {
    const kind = this.kind;
    if (!kind) return;
    const ring: LonLat[] = this.points.map((p) => [p.lng, p.lat]);
    const isLine = LINE_KINDS.includes(kind);
    this.stop();
    if (ring.length < (isLine ? 2 : 3)) {
      this.show(`<p>${isLine ? t("measure.lineTooShort") : t("measure.areaTooSmall")}</p>`);
      this.drawn.clearLayers();
      return;
    }
    const strong = (text: string) => `<strong>${escapeHtml(text)}</strong>`;
    if (kind === "distance") return this.show(`<p>${t("measure.distanceIs", { value: strong(formatMetres(pathLength(ring), 1)) })}</p>`);
    if (kind === "area") return this.show(`<p>${t("measure.areaIs", { value: strong(formatArea(polygonArea(ring))) })}</p>`);
    const context = this.context();
    if (!context) return this.show(`<p>${t("measure.openSite")}</p>`);
    this.show(`<p>${t("measure.measuring")}</p>`);
    try {
      if (kind === "profile") await this.profile(context, ring);
      else await this.volume(context, ring);
    } catch (error) {
      this.show(`<p class="error">${escapeHtml(error instanceof ApiError ? error.message : String(error))}</p>`);
    }
  }

  private async profile(context: MeasureContext, line: LonLat[]): Promise<void> {
    const owner = context.comparisonId !== null ? `comparisons/${context.comparisonId}` : context.surveyId !== null ? `surveys/${context.surveyId}` : null;
    if (!owner) return this.show(`<p>${t("measure.profileNeedsDsm")}</p>`);
    const profile = await postJson<ProfileData>(`sites/${context.siteId}/${owner}/profile`, {
      line: { type: "LineString", coordinates: line },
      samples: 300,
    });
    const title = context.comparisonId !== null ? "measure.profileOfPair" : "measure.profileOfSurvey";
    this.show(`<p>${t(title, { length: escapeHtml(formatMetres(profile.length_m, 1)) })}</p>${profileSvg(profile)}`);
  }

  private async volume(context: MeasureContext, ring: LonLat[]): Promise<void> {
    if (context.comparisonId === null) return this.show(`<p>${t("measure.volumeNeedsComparison")}</p>`);
    const closed = [...ring, ring[0]];
    const v = await postJson<VolumeAnswer>(`sites/${context.siteId}/comparisons/${context.comparisonId}/volume`, {
      polygon: { type: "Polygon", coordinates: [closed] },
    });
    const rows: Array<[string, string]> = [
      [t("measure.area"), formatArea(v.area_m2)],
      [t("measure.cut"), formatVolume(v.cut_m3)],
      [t("measure.fill"), formatVolume(v.fill_m3)],
      [t("measure.net"), `${v.net_m3 < 0 ? "−" : ""}${formatVolume(Math.abs(v.net_m3))}`],
      [t("measure.cutBeyondLod"), formatVolume(v.cut_beyond_lod_m3)],
      [t("measure.fillBeyondLod"), formatVolume(v.fill_beyond_lod_m3)],
      [t("measure.lod", { level: percent(95) }), formatMetres(v.lod_m)],
    ];
    const partial = v.measured_m2 < 0.95 * v.area_m2 ? `<p class="warning">${t("measure.partial", { area: formatArea(v.measured_m2) })}</p>` : "";
    this.show(
      `<table class="measure-volume">${rows.map(([k, val]) => `<tr><th scope="row">${escapeHtml(k)}</th><td>${escapeHtml(val)}</td></tr>`).join("")}</table>${partial}`,
    );
  }

  private show(html: string): void {
    this.result.innerHTML = html;
    (this.box.querySelector("details") as HTMLDetailsElement).open = true;
  }
}
