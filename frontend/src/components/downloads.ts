// Downloads of every product: a survey's DSM, orthophoto and point cloud, a comparison's
// Δh and probability rasters, its detections as GeoJSON, GeoPackage, KML and Shapefile.
// Each is fetched with the token in a header, so no link carries it.

import { getJson } from "../api";
import { escapeHtml, formatBytes, formatDate } from "../format";
import type { Comparison, Product, Survey } from "../types";
import { type MessageKey, t } from "../i18n";
import { download, failure } from "./tools";

// The pipeline's product kinds (worker/pipeline: reconstruction, comparison, methods).
const PRODUCT_KINDS = new Set([
  "dsm",
  "orthophoto",
  "points",
  "trajectory",
  "report",
  "dh",
  "post_coregistered",
  "significance",
  "lod",
  "probability",
  "cells",
  "detections",
]);

export function productName(kind: string): string {
  return PRODUCT_KINDS.has(kind) ? t(`product.${kind}` as MessageKey) : kind.replace(/_/g, " ");
}

/** The detection formats the API writes (…/detections/{format}); GeoJSON is …/detections. */
export const DETECTION_FORMATS: Array<[string, () => string]> = [
  ["geojson", () => "GeoJSON"],
  ["gpkg", () => "GeoPackage"],
  ["kml", () => "KML"],
  ["shp", () => t("downloads.shapefile")],
];

export function detectionsUrl(siteId: number, comparisonId: number, format: string): string {
  const base = `/api/v1/sites/${siteId}/comparisons/${comparisonId}/detections`;
  return format === "geojson" ? base : `${base}/${format}`;
}

function productItems(products: Product[]): string {
  // The comparison's detections file is offered below in every format, from the API.
  const shown = products.filter((p) => p.kind !== "detections");
  if (!shown.length) return `<li class="muted">${t("downloads.noProduct")}</li>`;
  return shown
    .map(
      (p) => `<li><button type="button" class="link-button" data-url="${escapeHtml(p.download_url)}"
        data-name="${escapeHtml(p.kind)}-${p.id}">${t("downloads.download", { product: escapeHtml(productName(p.kind)) })}</button>
        <span class="muted">${formatBytes(p.file.size_bytes)}</span></li>`,
    )
    .join("");
}

export class DownloadsPanel {
  private comparison: Comparison | null = null;

  constructor(
    private readonly box: HTMLElement,
    private readonly siteId: number,
    private readonly timeZone: string,
  ) {
    box.addEventListener("click", (event) => {
      const button = (event.target as HTMLElement).closest<HTMLButtonElement>("button[data-url]");
      if (!button) return;
      const error = box.querySelector(".error") as HTMLElement;
      error.textContent = "";
      download(button.dataset.url ?? "", button.dataset.name ?? "download").catch((e) => {
        error.textContent = failure(e);
      });
    });
  }

  async show(surveys: Survey[], comparison: Comparison | null): Promise<void> {
    this.comparison = comparison;
    const ready = surveys.filter((s) => s.status === "ready");
    const surveyProducts = await Promise.all(
      ready.map((s) => getJson<Product[]>(`sites/${this.siteId}/surveys/${s.id}/products`).catch(() => [])),
    );
    let comparisonHtml = `<p class="muted">${t("downloads.showComparison")}</p>`;
    if (comparison && comparison.status === "succeeded") {
      const products = await getJson<Product[]>(`sites/${this.siteId}/comparisons/${comparison.id}/products`).catch(
        () => [] as Product[],
      );
      const formats = DETECTION_FORMATS.map(
        ([format, name]) => `<li><button type="button" class="link-button" data-format="${format}"
          data-url="${detectionsUrl(this.siteId, comparison.id, format)}"
          data-name="comparison-${comparison.id}-detections.${format === "shp" ? "shp.zip" : format}">${t("downloads.detectionsAs", { format: name() })}</button></li>`,
      ).join("");
      comparisonHtml = `<h4>${t("downloads.comparison", { id: comparison.id })}</h4>
        <ul class="plain" data-role="comparison-products">${productItems(products)}${formats}</ul>`;
    }
    const surveysHtml = ready.length
      ? ready
          .map(
            (s, i) => `<h4>${escapeHtml(s.name)} <span class="muted">${formatDate(s.captured_at, this.timeZone)}</span></h4>
              <ul class="plain" data-survey-products="${s.id}">${productItems(surveyProducts[i])}</ul>`,
          )
          .join("")
      : `<p class="muted">${t("downloads.noSurvey")}</p>`;
    this.box.innerHTML = `${comparisonHtml}${surveysHtml}
      <p class="muted">${t("downloads.reportsElsewhere")}</p><p class="error" role="alert"></p>`;
  }

  get shown(): Comparison | null {
    return this.comparison;
  }
}
