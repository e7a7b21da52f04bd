// The site's map: pre and post surveys (their orthophotos, or their DSMs as elevation colours
// over hillshade), Δh, detections and their patch cells, survey footprints and flight
// trajectories; swipe, opacity, legends.
// Leaflet draws vectors on a Canvas 2D renderer; there is no basemap unless one is set.

import L from "leaflet";
import "leaflet/dist/leaflet.css";
import { authHeaders, getJson, putJson } from "../api";
import { symmetricRange, unionRange } from "../colormap";
import { cellStyle, detectionPopupHtml, detectionStyle, type HistoryEntry, historyHtml } from "../detections";
import { escapeHtml, formatDate, formatMetres } from "../format";
import { type MessageKey, t } from "../i18n";
import type { Comparison, DetectionFeature, MapConfig, Product, Site, Survey, TileJson, Verdict } from "../types";
import { correctionText } from "./alignment";
import { differenceLegend, elevationLegend, scoreLegend } from "./legend";
import { MeasureTool } from "./measure";
import { clearPopup } from "./popupClearance";
import { type SwipeSide, sideClip, swipeClips } from "./swipe";
import { type Owner, productTileLayer, tileJson, tileTemplate } from "./tiles";
import { formatLatLon, formatUtm, toUtm } from "./utm";

/** Marks a legend with the layers it explains (it hides while they are all off). */
function forLayers(legend: HTMLElement, ...keys: LayerKey[]): HTMLElement {
  legend.dataset.layers = keys.join(" ");
  return legend;
}

/** What the map did with the post survey: moved by the comparison's correction, or not. */
function alignmentNote(comparison: Comparison, corrected: boolean): HTMLElement {
  const note = document.createElement("p");
  note.className = "alignment-note";
  note.dataset.legend = "alignment";
  const text = correctionText(comparison.summary);
  if (!text) note.textContent = t("map.noCorrection");
  else if (corrected) note.textContent = t("map.corrected", { correction: text });
  else note.textContent = t("map.notCorrected", { correction: text });
  return note;
}

/** The centre of a detection's polygon (of its bounds), as [lat, lon]. */
function centreOf(layer: L.Layer | null): [number, number] | undefined {
  const bounded = layer as (L.Layer & { getBounds?: () => L.LatLngBounds }) | null;
  const centre = bounded?.getBounds?.().getCenter();
  return centre ? [centre.lat, centre.lng] : undefined;
}

function layerOf(popup: L.Popup): L.Layer | null {
  return (popup as unknown as { _source?: L.Layer })._source ?? null;
}

type LayerKey = "pre" | "post" | "dh" | "detections" | "cells" | "footprints" | "trajectories";
/** What the pre and post layers show: a survey's orthophoto (imagery, where it has one) or its DSM. */
export type SurveyView = "orthophoto" | "dsm";

const PANES: Record<string, number> = {
  pre: 250,
  post: 260,
  dh: 270,
  footprints: 410,
  trajectories: 415,
  cells: 420,
  detections: 430,
};

const LABELS: Record<LayerKey, MessageKey> = {
  pre: "map.layerPre",
  post: "map.layerPost",
  dh: "map.layerDh",
  detections: "map.layerDetections",
  cells: "map.layerCells",
  footprints: "map.layerFootprints",
  trajectories: "map.layerTrajectories",
};

const RASTERS: LayerKey[] = ["pre", "post", "dh"];
/** Layers drawn over the surveys: while swiping, each on the side (or sides) chosen for it. */
const OVERLAYS: LayerKey[] = ["dh", "detections", "cells", "footprints", "trajectories"];
// While swiping, what the comparison found belongs with the post survey (right); the
// outlines of what was flown belong with both.
const DEFAULT_SIDES: Record<string, SwipeSide> = {
  dh: "right",
  detections: "right",
  cells: "right",
  footprints: "both",
  trajectories: "both",
};
const SIDE_LABELS: Record<SwipeSide, MessageKey> = {
  both: "map.swipeSideBoth",
  left: "map.swipeSidePre",
  right: "map.swipeSidePost",
};

export interface ShownPair {
  pre: Survey | null;
  post: Survey | null;
  comparison: Comparison | null;
}

export class MapView {
  readonly map: L.Map;
  private readonly groups = new Map<LayerKey, L.LayerGroup>();
  private readonly visible = new Map<LayerKey, boolean>();
  private readonly opacity = new Map<LayerKey, number>([
    ["pre", 1],
    ["post", 1],
    ["dh", 0.85],
  ]);
  private readonly legendBox: HTMLElement;
  private readonly legendControl: HTMLElement;
  private readonly controlsBox: HTMLElement;
  private readonly swipeBox: HTMLElement;
  private readonly cursorBox: HTMLElement;
  private heightsTimer: number | undefined;
  // The pre and post layers' legends, first in the legend box.
  private readonly surveyLegends = document.createElement("div");
  readonly measure: MeasureTool;
  private swipeOn = false;
  private readonly swipeSides = new Map<LayerKey, SwipeSide>(Object.entries(DEFAULT_SIDES) as [LayerKey, SwipeSide][]);
  private swipeFraction = 0.5;
  private siteBounds: L.LatLngBounds | null = null;
  private detectionLayers = new Map<number, L.Path>();
  private site: Site | null = null;
  private generation = 0;
  // Imagery first: people read an orthophoto at a glance; a survey without one (a DSM
  // upload) shows its DSM either way.
  private surveyView: SurveyView = "orthophoto";
  private postAsUploaded = false;
  // Stepping through the site's surveys in time: the index of the one shown alone, or null.
  private timeIndex: number | null = null;
  private readySurveys: Survey[] = [];
  private readonly timeBox: HTMLElement;
  private sharedStretch = false;
  private shown: ShownPair | null = null;

  constructor(container: HTMLElement, config: MapConfig) {
    this.map = L.map(container, {
      preferCanvas: true,
      zoomSnap: 1, // whole zoom levels: scaled tiles would show seams between them
      maxZoom: 24,
      attributionControl: true,
      keyboard: true,
    });
    this.map.attributionControl.setPrefix(false);
    for (const [pane, z] of Object.entries(PANES)) this.map.createPane(pane).style.zIndex = String(z);
    if (config.basemap_url) {
      L.tileLayer(config.basemap_url, { attribution: escapeHtml(config.basemap_attribution), maxZoom: 19 }).addTo(this.map);
    } else {
      this.map.attributionControl.addAttribution(t("map.noBasemap"));
    }
    for (const key of Object.keys(LABELS) as LayerKey[]) {
      this.groups.set(key, L.layerGroup().addTo(this.map));
      this.visible.set(key, true);
    }
    this.map.setView([0, 0], 2);
    this.controlsBox = this.addControl("topright", "map-controls");
    // The legends fold away (folded at first on a phone, where they would cover the map).
    const legends = (this.legendControl = this.addControl("bottomleft", "map-legends"));
    legends.innerHTML = `<details ${window.innerWidth > 600 ? "open" : ""}><summary>${t("map.legend")}</summary><div class="legend-body"></div></details>`;
    this.legendBox = legends.querySelector(".legend-body") as HTMLElement;
    this.swipeBox = this.buildSwipe(container);
    this.renderControls();
    this.map.on("move zoom resize viewreset", () => this.applySwipe());
    // The divider is drawn over the map's panes, popups included: it steps aside while a
    // popup is open rather than cut through its text.
    this.map.on("popupopen", () => this.swipeBox.classList.add("popup-open"));
    this.map.on("popupclose", () => this.swipeBox.classList.remove("popup-open"));
    L.control.scale({ metric: true, imperial: false, position: "bottomright", maxWidth: 160 }).addTo(this.map);
    this.cursorBox = this.addControl("bottomright", "map-cursor");
    this.cursorBox.setAttribute("aria-live", "off");
    this.cursorBox.textContent = t("map.cursorHint");
    this.map.on("mousemove", (event: L.LeafletMouseEvent) => this.showCursor(event.latlng));
    this.timeBox = this.addControl("topleft", "map-time");
    this.renderTime();
    this.measure = new MeasureTool(this.map, () =>
      this.site
        ? {
            siteId: this.site.id,
            comparisonId: this.shown?.comparison?.status === "succeeded" ? this.shown.comparison.id : null,
            surveyId: this.shown?.post?.status === "ready" ? this.shown.post.id : this.shown?.pre?.status === "ready" ? this.shown.pre.id : null,
          }
        : null,
    );
  }

  /** Where the pointer is: latitude/longitude and UTM (the site's zone, from its longitude). */
  private showCursor(at: L.LatLng): void {
    const lon = L.Util.wrapNum(at.lng, [-180, 180], true);
    this.cursorBox.innerHTML = `${escapeHtml(formatLatLon(at.lat, lon))}<br>UTM ${escapeHtml(formatUtm(toUtm(at.lat, lon)))}<br><span data-role="heights"></span>`;
    // The heights under the pointer, asked for once it rests (a request per move would
    // flood the API).
    if (this.heightsTimer !== undefined) window.clearTimeout(this.heightsTimer);
    this.heightsTimer = window.setTimeout(() => void this.showHeights(at.lat, lon), 250);
  }

  private async showHeights(lat: number, lon: number): Promise<void> {
    const site = this.site;
    const pair = this.shown;
    if (!site || !pair) return;
    const timeSurvey = this.timeIndex !== null ? this.readySurveys[this.timeIndex] : null;
    const comparison = !timeSurvey && pair.comparison?.status === "succeeded" ? pair.comparison : null;
    const survey = timeSurvey ?? (pair.post?.status === "ready" ? pair.post : null);
    const path = comparison ? `comparisons/${comparison.id}` : survey ? `surveys/${survey.id}` : null;
    if (!path) return;
    const heights = await getJson<Record<string, number | null>>(`sites/${site.id}/${path}/heights?lon=${lon}&lat=${lat}`).catch(() => null);
    const box = this.cursorBox.querySelector("[data-role=heights]");
    if (!heights || !box) return;
    const words: Record<string, string> = {
      pre: t("map.heightPre"),
      post: t("map.heightPost"),
      dh: "Δh",
      dsm: timeSurvey ? timeSurvey.name : t("map.heightDsm"),
    };
    box.textContent = Object.entries(heights)
      .filter(([, value]) => value !== null)
      .map(([name, value]) => `${words[name] ?? name} ${formatMetres(value, 2)}`)
      .join(" · ");
  }

  private addControl(position: L.ControlPosition, className: string): HTMLElement {
    const box = L.DomUtil.create("div", `leaflet-bar ${className}`);
    L.DomEvent.disableClickPropagation(box);
    L.DomEvent.disableScrollPropagation(box);
    const control = new L.Control({ position });
    control.onAdd = () => box;
    control.addTo(this.map);
    return box;
  }

  private buildSwipe(container: HTMLElement): HTMLElement {
    const box = document.createElement("div");
    box.className = "swipe";
    box.hidden = true;
    // The tags ride on the divider, each on its side of it.
    box.innerHTML = `<div class="swipe-line" aria-hidden="true"><div class="swipe-handle"></div>
      <span class="swipe-tag left">${t("map.swipePre")}</span><span class="swipe-tag right">${t("map.swipePost")}</span></div>
      <label class="swipe-input"><span class="visually-hidden">${t("map.swipePosition")}</span>
      <input type="range" min="0" max="100" step="1" value="50" id="swipe-range"></label>`;
    const input = box.querySelector("input") as HTMLInputElement;
    input.addEventListener("input", () => {
      this.swipeFraction = Number(input.value) / 100;
      this.applySwipe();
    });
    // The divider itself is draggable too (the slider stays for keyboards and a thumb).
    const line = box.querySelector(".swipe-line") as HTMLElement;
    line.addEventListener("pointerdown", (down) => {
      down.preventDefault();
      line.setPointerCapture(down.pointerId);
      const move = (event: PointerEvent) => {
        const rect = container.getBoundingClientRect();
        this.swipeFraction = Math.min(1, Math.max(0, (event.clientX - rect.left) / rect.width));
        input.value = String(Math.round(this.swipeFraction * 100));
        this.applySwipe();
      };
      const up = () => {
        line.removeEventListener("pointermove", move);
        line.removeEventListener("pointerup", up);
        line.removeEventListener("pointercancel", up);
      };
      line.addEventListener("pointermove", move);
      line.addEventListener("pointerup", up);
      line.addEventListener("pointercancel", up);
    });
    L.DomEvent.disableClickPropagation(box);
    // Leaflet drags the map on pointer events: dragging the divider must not pan it.
    L.DomEvent.on(box, "pointerdown touchstart", L.DomEvent.stopPropagation);
    container.append(box);
    return box;
  }

  /** Pre left of the divider, post right of it, and each overlay on its chosen side: every
   * layer's pane is clipped (CSS `clip`, in the panes' layer pixels) to its side. */
  private applySwipe(): void {
    const pane = (key: LayerKey) => this.map.getPane(key) as HTMLElement;
    const line = this.swipeBox.querySelector(".swipe-line") as HTMLElement;
    if (!this.swipeOn) {
      for (const key of ["pre", "post", ...OVERLAYS] as LayerKey[]) pane(key).style.clip = "";
      return;
    }
    const size = this.map.getSize();
    const topLeft = this.map.containerPointToLayerPoint([0, 0]);
    const bottomRight = this.map.containerPointToLayerPoint(size);
    const clips = swipeClips(topLeft, bottomRight, this.swipeFraction);
    pane("pre").style.clip = clips.left;
    pane("post").style.clip = clips.right;
    for (const key of OVERLAYS) pane(key).style.clip = sideClip(this.swipeSides.get(key) ?? "both", clips);
    line.style.left = `${this.swipeFraction * 100}%`;
  }

  setSwipe(on: boolean): void {
    this.swipeOn = on;
    this.swipeBox.hidden = !on;
    if (on) {
      this.setVisible("pre", true);
      this.setVisible("post", true);
    }
    this.applySwipe();
    this.renderControls();
  }

  /** While swiping, draw an overlay on the left (pre) side, the right (post) or both. */
  setSwipeSide(key: LayerKey, side: SwipeSide): void {
    this.swipeSides.set(key, side);
    this.applySwipe();
  }

  /** A legend shows while one of the layers it explains is on. */
  private applyLegendVisibility(): void {
    let shown = 0;
    this.legendBox.querySelectorAll<HTMLElement>("[data-layers]").forEach((legend) => {
      legend.hidden = !(legend.dataset.layers ?? "").split(" ").some((key) => this.visible.get(key as LayerKey));
      if (!legend.hidden) shown += 1;
    });
    this.legendControl.hidden = shown === 0; // no empty "Legend" box
  }

  private setVisible(key: LayerKey, on: boolean): void {
    this.visible.set(key, on);
    this.applyLegendVisibility();
    const group = this.groups.get(key) as L.LayerGroup;
    if (on && !this.map.hasLayer(group)) group.addTo(this.map);
    if (!on && this.map.hasLayer(group)) group.remove();
  }

  private setOpacity(key: LayerKey, value: number): void {
    this.opacity.set(key, value);
    (this.map.getPane(key) as HTMLElement).style.opacity = String(value);
  }

  private renderControls(): void {
    const rows = (Object.keys(LABELS) as LayerKey[])
      .map((key) => {
        const checked = this.visible.get(key) ? "checked" : "";
        const slider = RASTERS.includes(key)
          ? `<label class="opacity"><span class="visually-hidden">${escapeHtml(t("map.opacity", { layer: t(LABELS[key]) }))}</span>
             <input type="range" min="0" max="100" value="${Math.round((this.opacity.get(key) ?? 1) * 100)}" data-opacity="${key}" aria-label="${escapeHtml(t("map.opacityPercent", { layer: t(LABELS[key]) }))}"></label>`
          : "";
        return `<div class="layer-row"><label><input type="checkbox" data-layer="${key}" ${checked}> ${escapeHtml(t(LABELS[key]))}</label>${slider}${this.sideChoice(key)}</div>`;
      })
      .join("");
    // Open on a laptop; folded on a narrow (tablet portrait) screen until asked for.
    const open = (this.controlsBox.querySelector("details") as HTMLDetailsElement | null)?.open ?? window.innerWidth > 900;
    const view = (value: SurveyView, label: string) =>
      `<label><input type="radio" name="survey-view" value="${value}" ${this.surveyView === value ? "checked" : ""}> ${label}</label>`;
    this.controlsBox.innerHTML = `<details ${open ? "open" : ""}><summary>${t("map.layers")}</summary>
      <fieldset class="layer-row survey-view"><legend>${t("map.surveysShow")}</legend>${view("orthophoto", t("map.orthophoto"))}${view("dsm", t("map.dsm"))}</fieldset>${rows}
      <div class="layer-row"><label><input type="checkbox" id="swipe-toggle" ${this.swipeOn ? "checked" : ""}> ${t("map.swipe")}</label></div>
      <div class="layer-row"><label><input type="checkbox" id="post-as-uploaded" ${this.postAsUploaded ? "checked" : ""}> ${t("map.postAsUploaded")}</label></div>
      <div class="layer-row"><label><input type="checkbox" id="shared-stretch" ${this.sharedStretch ? "checked" : ""}> ${t("map.sharedStretch")}</label></div>
      <button type="button" id="zoom-site">${t("map.zoomToSite")}</button></details>`;
    this.controlsBox.querySelectorAll<HTMLInputElement>("input[data-layer]").forEach((input) =>
      input.addEventListener("change", () => this.setVisible(input.dataset.layer as LayerKey, input.checked)),
    );
    this.controlsBox.querySelectorAll<HTMLSelectElement>("select[data-side]").forEach((select) =>
      select.addEventListener("change", () => this.setSwipeSide(select.dataset.side as LayerKey, select.value as SwipeSide)),
    );
    this.controlsBox.querySelectorAll<HTMLInputElement>("input[data-opacity]").forEach((input) =>
      input.addEventListener("input", () => this.setOpacity(input.dataset.opacity as LayerKey, Number(input.value) / 100)),
    );
    (this.controlsBox.querySelector("#swipe-toggle") as HTMLInputElement).addEventListener("change", (e) =>
      this.setSwipe((e.target as HTMLInputElement).checked),
    );
    (this.controlsBox.querySelector("#zoom-site") as HTMLButtonElement).addEventListener("click", () => this.zoomToSite());
    (this.controlsBox.querySelector("#post-as-uploaded") as HTMLInputElement).addEventListener("change", (e) => {
      this.postAsUploaded = (e.target as HTMLInputElement).checked;
      void this.redraw();
    });
    (this.controlsBox.querySelector("#shared-stretch") as HTMLInputElement).addEventListener("change", (e) => {
      this.sharedStretch = (e.target as HTMLInputElement).checked;
      void this.redraw();
    });
    this.controlsBox.querySelectorAll<HTMLInputElement>("input[name=survey-view]").forEach((input) =>
      input.addEventListener("change", () => void this.setSurveyView(input.value as SurveyView)),
    );
  }

  /** While swiping, an overlay's row chooses the side of the divider it is drawn on. */
  private sideChoice(key: LayerKey): string {
    if (!this.swipeOn || !OVERLAYS.includes(key)) return "";
    const chosen = this.swipeSides.get(key) ?? "both";
    const options = (Object.keys(SIDE_LABELS) as SwipeSide[])
      .map((side) => `<option value="${side}" ${side === chosen ? "selected" : ""}>${escapeHtml(t(SIDE_LABELS[side]))}</option>`)
      .join("");
    return `<label class="swipe-side"><span class="visually-hidden">${escapeHtml(t("map.swipeSideOf", { layer: t(LABELS[key]) }))}</span>
      <select data-side="${key}">${options}</select></label>`;
  }

  /** Show the pre and post surveys as orthophotos (where they have one) or as DSMs. */
  async setSurveyView(view: SurveyView): Promise<void> {
    if (view === this.surveyView) return;
    this.surveyView = view;
    this.renderControls();
    await this.redraw();
  }

  private async redraw(): Promise<void> {
    if (this.shown) await this.showSurveyLayers(this.shown, this.generation);
  }

  zoomToSite(): void {
    if (this.siteBounds?.isValid()) this.map.fitBounds(this.siteBounds, { padding: [20, 20] });
  }

  /** Footprints and trajectories of every survey of the site. */
  async showSurveys(site: Site, surveys: Survey[]): Promise<void> {
    this.site = site;
    const shownBefore = this.timeIndex !== null ? this.readySurveys[this.timeIndex]?.id : undefined;
    this.readySurveys = surveys
      .filter((s) => s.status === "ready")
      .sort((a, b) => a.captured_at.localeCompare(b.captured_at));
    if (this.timeIndex !== null) {
      const kept = this.readySurveys.findIndex((s) => s.id === shownBefore);
      this.timeIndex = kept >= 0 ? kept : this.readySurveys.length ? this.readySurveys.length - 1 : null;
    }
    this.renderTime();
    const footprints = this.groups.get("footprints") as L.LayerGroup;
    const trajectories = this.groups.get("trajectories") as L.LayerGroup;
    footprints.clearLayers();
    trajectories.clearLayers();
    const bounds = L.latLngBounds([]);
    if (site.area_of_interest) bounds.extend(L.geoJSON(site.area_of_interest).getBounds());
    for (const survey of surveys) {
      if (!survey.footprint) continue;
      const layer = L.geoJSON(survey.footprint, {
        pane: "footprints",
        style: { color: "#1f2937", weight: 1.5, dashArray: "6 4", fill: false },
      });
      layer.bindTooltip(`${escapeHtml(survey.name)} (${formatDate(survey.captured_at, site.timezone)})`);
      footprints.addLayer(layer);
      bounds.extend(layer.getBounds());
    }
    for (const survey of surveys.filter((s) => s.kind !== "dsm" && s.status === "ready")) {
      const products = await getJson<Product[]>(`sites/${site.id}/surveys/${survey.id}/products`);
      const trajectory = products.find((p) => p.kind === "trajectory");
      if (!trajectory) continue;
      const geojson = await fetch(trajectory.download_url, { headers: authHeaders() }).then((r) => r.json());
      const line = L.geoJSON(geojson, { pane: "trajectories", style: { color: "#0ea5e9", weight: 2 } });
      line.bindTooltip(t("map.flightOf", { name: escapeHtml(survey.name) }));
      trajectories.addLayer(line);
      bounds.extend(line.getBounds());
    }
    if (bounds.isValid()) {
      const first = this.siteBounds === null;
      this.siteBounds = bounds;
      if (first) this.zoomToSite();
    }
  }

  /** The pre and post DSMs, and a comparison's Δh and detections when there is one. */
  async showPair(pair: ShownPair): Promise<DetectionFeature[]> {
    this.shown = pair;
    const site = this.site as Site;
    const generation = ++this.generation;
    for (const key of ["dh", "detections", "cells"] as LayerKey[]) this.groups.get(key)?.clearLayers();
    this.detectionLayers.clear();
    this.legendBox.innerHTML = "";
    this.legendBox.append(this.surveyLegends);
    await this.showSurveyLayers(pair, generation);
    if (generation !== this.generation) return [];
    let features: DetectionFeature[] = [];
    const comparison = pair.comparison;
    if (comparison && comparison.status === "succeeded") {
      const owner: Owner = { kind: "comparisons", id: comparison.id };
      const info = await tileJson(site.id, owner, "dh").catch(() => null);
      if (info && generation === this.generation) {
        const range = symmetricRange(info.rescale);
        (this.groups.get("dh") as L.LayerGroup).addLayer(
          productTileLayer(tileTemplate(site.id, owner, "dh", range), info, "dh"),
        );
        this.legendBox.append(forLayers(differenceLegend(range), "dh"));
      }
      // A comparison deleted while it was being drawn: a newer showPair has taken over.
      features = await this.showDetections(site, comparison).catch((error: unknown) => {
        if (generation !== this.generation) return [];
        throw error;
      });
      this.legendBox.append(forLayers(scoreLegend(), "detections"));
    }
    for (const key of RASTERS) this.setOpacity(key, this.opacity.get(key) ?? 1);
    this.applyLegendVisibility();
    this.applySwipe();
    return features;
  }

  /** The pre and post layers (orthophotos or DSMs, the post one co-registered unless asked
   * otherwise) and their legends; drawn again alone when those choices change. */
  private async showSurveyLayers(pair: ShownPair, generation: number): Promise<void> {
    const site = this.site as Site;
    if (this.timeIndex !== null && this.readySurveys[this.timeIndex]) {
      return this.showOneSurvey(this.readySurveys[this.timeIndex], generation);
    }
    const surveyOwner = (s: Survey | null): Owner | null => (s && s.status === "ready" ? { kind: "surveys", id: s.id } : null);
    const owners = { pre: surveyOwner(pair.pre), post: surveyOwner(pair.post) };
    const done = pair.comparison && pair.comparison.status === "succeeded" ? pair.comparison : null;
    // The post survey drawn where the comparison put it (the co-registration's correction),
    // unless asked for as uploaded: both are said in the legend.
    const corrected = done !== null && !this.postAsUploaded && owners.post !== null;
    const dsmOwners: Record<"pre" | "post", Owner | null> = {
      pre: owners.pre,
      post: corrected && done ? { kind: "comparisons", id: done.id } : owners.post,
    };
    const infos: Record<"pre" | "post", TileJson | null> = { pre: null, post: null };
    const orthophotos: Record<"pre" | "post", TileJson | null> = { pre: null, post: null };
    for (const side of ["pre", "post"] as const) {
      const owner = dsmOwners[side];
      if (!owner) continue;
      infos[side] = await tileJson(site.id, owner, "dsm").catch(() => null);
      // A survey made from video or photos has an orthophoto; an uploaded DSM has none (404).
      const survey = owners[side];
      if (this.surveyView === "orthophoto" && survey) orthophotos[side] = await tileJson(site.id, survey, "orthophoto").catch(() => null);
    }
    if (generation !== this.generation) return;
    for (const side of ["pre", "post"] as const) this.groups.get(side)?.clearLayers();
    this.surveyLegends.innerHTML = "";
    const asDsm = (["pre", "post"] as const).filter((side) => infos[side] && !orthophotos[side]);
    const shared = unionRange(asDsm.map((side) => infos[side]?.rescale));
    for (const side of ["pre", "post"] as const) {
      const owner = dsmOwners[side];
      const survey = owners[side];
      const info = infos[side];
      if (!owner || !survey || !info) continue;
      const group = this.groups.get(side) as L.LayerGroup;
      const orthophoto = orthophotos[side];
      if (orthophoto) {
        const moved = side === "post" && corrected && done ? `?coregistered_by=${done.id}` : "";
        group.addLayer(productTileLayer(tileTemplate(site.id, survey, "orthophoto") + moved, orthophoto, side));
        continue;
      }
      // Each DSM in its own stretch by default: two flights metres apart in height would
      // otherwise each show in half the colours.
      const range = this.sharedStretch ? shared : info.rescale;
      group.addLayer(productTileLayer(tileTemplate(site.id, owner, "hillshade"), info, side));
      const colours = productTileLayer(tileTemplate(site.id, owner, "dsm", range ?? undefined), info, side);
      colours.setOpacity(0.6); // the hillshade shows through the elevation colours
      group.addLayer(colours);
      if (!this.sharedStretch && range) this.surveyLegends.append(forLayers(elevationLegend(range, t(side === "pre" ? "map.preDsm" : "map.postDsm"), `elevation-${side}`), side));
    }
    if (this.sharedStretch && shared && asDsm.length) this.surveyLegends.append(forLayers(elevationLegend(shared), ...asDsm));
    if (done && owners.post) this.surveyLegends.append(forLayers(alignmentNote(done, corrected), "post"));
    this.applyLegendVisibility();
    for (const side of ["pre", "post"] as const) this.setOpacity(side, this.opacity.get(side) ?? 1);
    this.applySwipe();
  }

  /** One survey alone (stepping through time): its orthophoto, or its DSM over hillshade. */
  private async showOneSurvey(survey: Survey, generation: number): Promise<void> {
    const site = this.site as Site;
    const owner: Owner = { kind: "surveys", id: survey.id };
    const info = await tileJson(site.id, owner, "dsm").catch(() => null);
    const orthophoto = this.surveyView === "orthophoto" ? await tileJson(site.id, owner, "orthophoto").catch(() => null) : null;
    if (generation !== this.generation) return;
    for (const side of ["pre", "post"] as const) this.groups.get(side)?.clearLayers();
    this.surveyLegends.innerHTML = "";
    const group = this.groups.get("post") as L.LayerGroup;
    if (orthophoto) group.addLayer(productTileLayer(tileTemplate(site.id, owner, "orthophoto"), orthophoto, "post"));
    else if (info) {
      group.addLayer(productTileLayer(tileTemplate(site.id, owner, "hillshade"), info, "post"));
      const colours = productTileLayer(tileTemplate(site.id, owner, "dsm", info.rescale ?? undefined), info, "post");
      colours.setOpacity(0.6);
      group.addLayer(colours);
      if (info.rescale) this.surveyLegends.append(forLayers(elevationLegend(info.rescale, escapeHtml(survey.name)), "post"));
    }
    this.setOpacity("post", this.opacity.get("post") ?? 1);
    this.applyLegendVisibility();
    this.applySwipe();
  }

  /** The time stepper: every ready survey of the site in time order, one at a time. */
  private renderTime(): void {
    const n = this.readySurveys.length;
    const on = this.timeIndex !== null;
    const survey = on ? this.readySurveys[this.timeIndex as number] : null;
    const when = survey ? formatDate(survey.captured_at, this.site?.timezone ?? "UTC") : "";
    const open = (this.timeBox.querySelector("details") as HTMLDetailsElement | null)?.open ?? false;
    this.timeBox.innerHTML = `<details ${open ? "open" : ""}><summary>${t("map.time")}</summary>
      <label><input type="checkbox" id="time-toggle" ${on ? "checked" : ""} ${n ? "" : "disabled"}> ${t("map.stepThrough", { count: n })}</label>
      <label class="time-range"><span class="visually-hidden">${t("map.surveyShown")}</span>
        <input type="range" id="time-range" min="0" max="${Math.max(0, n - 1)}" step="1" value="${this.timeIndex ?? Math.max(0, n - 1)}" ${on ? "" : "disabled"}
          aria-valuetext="${survey ? `${escapeHtml(survey.name)}, ${when}` : t("map.off")}"></label>
      <p class="time-label" aria-live="polite">${survey ? t("map.timeLabel", { name: escapeHtml(survey.name), date: escapeHtml(when), n: (this.timeIndex as number) + 1, count: n }) : ""}</p></details>`;
    (this.timeBox.querySelector("#time-toggle") as HTMLInputElement).addEventListener("change", (e) => {
      this.timeIndex = (e.target as HTMLInputElement).checked && n ? n - 1 : null;
      this.renderTime();
      (this.timeBox.querySelector((e.target as HTMLInputElement).checked ? "#time-range" : "#time-toggle") as HTMLElement).focus();
      void this.redraw();
    });
    const range = this.timeBox.querySelector("#time-range") as HTMLInputElement;
    range.addEventListener("input", () => {
      this.timeIndex = Number(range.value);
      const shown = this.readySurveys[this.timeIndex];
      const label = this.timeBox.querySelector(".time-label") as HTMLElement;
      const date = formatDate(shown.captured_at, this.site?.timezone ?? "UTC");
      label.textContent = t("map.timeLabel", { name: shown.name, date, n: this.timeIndex + 1, count: n });
      range.setAttribute("aria-valuetext", `${shown.name}, ${date}`);
      void this.redraw();
    });
  }

  private async showDetections(site: Site, comparison: Comparison): Promise<DetectionFeature[]> {
    const base = `sites/${site.id}/comparisons/${comparison.id}`;
    const [collection, cells] = await Promise.all([
      getJson<GeoJSON.FeatureCollection>(`${base}/detections`),
      getJson<GeoJSON.FeatureCollection>(`${base}/cells`),
    ]);
    const features = collection.features as DetectionFeature[];
    const cellRenderer = L.canvas({ pane: "cells" });
    (this.groups.get("cells") as L.LayerGroup).addLayer(
      L.geoJSON(cells, { style: () => cellStyle(), renderer: cellRenderer } as L.GeoJSONOptions),
    );
    const renderer = L.canvas({ pane: "detections", tolerance: 3 });
    const group = this.groups.get("detections") as L.LayerGroup;
    for (const feature of features) {
      const layer = L.geoJSON(feature, {
        style: () => detectionStyle(feature.properties.score),
        renderer,
      } as L.GeoJSONOptions);
      layer.eachLayer((path) => {
        const polygon = path as L.Path;
        // Scrolls rather than overflows a short (phone) map, and pans clear of its controls.
        const popup = clearPopup({ maxWidth: Math.min(320, this.map.getSize().x - 40) });
        polygon.bindPopup(
          popup.setContent(() => detectionPopupHtml(feature.id, feature.properties, site.timezone, centreOf(polygon))),
        );
        polygon.on("popupopen", (event: L.PopupEvent) => this.wireVerdicts(event.popup, site, comparison, feature));
        this.detectionLayers.set(feature.id, polygon);
      });
      group.addLayer(layer);
    }
    return features;
  }

  private wireVerdicts(popup: L.Popup, site: Site, comparison: Comparison, feature: DetectionFeature): void {
    const element = popup.getElement();
    if (!element) return;
    (element.querySelector("button[data-verdict]") as HTMLButtonElement | null)?.focus();
    const history = element.querySelector<HTMLButtonElement>("button[data-history]");
    history?.addEventListener("click", async () => {
      const box = element.querySelector("[data-role=history]") as HTMLElement;
      box.textContent = t("common.loading");
      const url = `sites/${site.id}/comparisons/${comparison.id}/detections/${feature.id}/history`;
      // Written into the open popup (popup.update() would render its content anew).
      box.innerHTML = historyHtml(await getJson<HistoryEntry[]>(url), site.timezone);
    });
    const copy = element.querySelector<HTMLButtonElement>("button[data-position]");
    copy?.addEventListener("click", async () => {
      try {
        await navigator.clipboard.writeText(copy.dataset.position ?? "");
        copy.textContent = t("map.copied");
      } catch {
        copy.textContent = t("map.copyFailed");
      }
    });
    element.querySelectorAll<HTMLButtonElement>("button[data-verdict]").forEach((button) =>
      button.addEventListener("click", async () => {
        const verdict = button.dataset.verdict as Verdict;
        const url = `sites/${site.id}/comparisons/${comparison.id}/detections/${feature.id}/feedback`;
        const saved = await putJson<{ author: string; updated_at: string }>(url, { verdict });
        const summary = feature.properties.feedback;
        summary.latest = { verdict, author: saved.author, at: saved.updated_at };
        const all = await getJson<Array<{ verdict: Verdict }>>(url);
        summary.confirmed = all.filter((f) => f.verdict === "confirmed").length;
        summary.false_alarm = all.filter((f) => f.verdict === "false_alarm").length;
        popup.setContent(detectionPopupHtml(feature.id, feature.properties, site.timezone, centreOf(layerOf(popup))));
        this.wireVerdicts(popup, site, comparison, feature);
      }),
    );
  }

  /** Zoom to a detection and open its popup (the keyboard's way to the polygon). */
  openDetection(id: number): void {
    const layer = this.detectionLayers.get(id) as (L.Path & { getBounds(): L.LatLngBounds }) | undefined;
    if (!layer) return;
    this.setVisible("detections", true);
    // The list is below the map on a phone: bring the map back into view first.
    const box = this.map.getContainer().getBoundingClientRect();
    if (box.top < 0 || box.bottom > window.innerHeight) this.map.getContainer().scrollIntoView({ block: "nearest" });
    // Not animated: the popup's pan into view is measured on the settled view.
    this.map.fitBounds(layer.getBounds(), { padding: [60, 60], maxZoom: 23, animate: false });
    layer.openPopup(layer.getBounds().getCenter());
  }

  invalidateSize(): void {
    this.map.invalidateSize();
  }
}
