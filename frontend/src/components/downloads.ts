// Downloads of every product: a survey's DSM, orthophoto and point cloud, a comparison's
// Δh and probability rasters, its detections as GeoJSON, GeoPackage, KML and Shapefile.
// Each is fetched with the token in a header, so no link carries it.

import { getJson } from "../api";
import { escapeHtml, formatBytes, formatDate } from "../format";
import type { Comparison, Product, Survey } from "../types";
import { download, failure } from "./tools";

// The pipeline's product kinds (worker/pipeline: reconstruction, comparison, methods).
const PRODUCT_NAMES: Record<string, string> = {
  dsm: "DSM (Cloud-Optimized GeoTIFF)",
  orthophoto: "Orthophoto (Cloud-Optimized GeoTIFF)",
  points: "Point cloud (PLY)",
  trajectory: "Flight trajectory (GeoJSON)",
  report: "Reconstruction report (JSON)",
  dh: "Δh, elevation change (Cloud-Optimized GeoTIFF)",
  post_coregistered: "Post DSM co-registered onto pre (GeoTIFF)",
  significance: "Significant change mask (GeoTIFF)",
  lod: "Level of detection, LoD95 (GeoTIFF)",
  probability: "Landslide probability (Cloud-Optimized GeoTIFF)",
  cells: "Probability cells (GeoJSON)",
  detections: "Detections as stored by the pipeline (GeoJSON)",
};

export function productName(kind: string): string {
  return PRODUCT_NAMES[kind] ?? kind.replace(/_/g, " ");
}

/** The detection formats the API writes (…/detections/{format}); GeoJSON is …/detections. */
export const DETECTION_FORMATS: Array<[string, string]> = [
  ["geojson", "GeoJSON"],
  ["gpkg", "GeoPackage"],
  ["kml", "KML"],
  ["shp", "Shapefile (zip)"],
];

export function detectionsUrl(siteId: number, comparisonId: number, format: string): string {
  const base = `/api/v1/sites/${siteId}/comparisons/${comparisonId}/detections`;
  return format === "geojson" ? base : `${base}/${format}`;
}

function productItems(products: Product[]): string {
  // The comparison's detections file is offered below in every format, from the API.
  const shown = products.filter((p) => p.kind !== "detections");
  if (!shown.length) return `<li class="muted">No product yet.</li>`;
  return shown
    .map(
      (p) => `<li><button type="button" class="link-button" data-url="${escapeHtml(p.download_url)}"
        data-name="${escapeHtml(p.kind)}-${p.id}">Download ${escapeHtml(productName(p.kind))}</button>
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
    let comparisonHtml = `<p class="muted">Show a finished comparison to download its products.</p>`;
    if (comparison && comparison.status === "succeeded") {
      const products = await getJson<Product[]>(`sites/${this.siteId}/comparisons/${comparison.id}/products`).catch(
        () => [] as Product[],
      );
      const formats = DETECTION_FORMATS.map(
        ([format, name]) => `<li><button type="button" class="link-button" data-format="${format}"
          data-url="${detectionsUrl(this.siteId, comparison.id, format)}"
          data-name="comparison-${comparison.id}-detections.${format === "shp" ? "shp.zip" : format}">Detections as ${name}</button></li>`,
      ).join("");
      comparisonHtml = `<h4>Comparison ${comparison.id}</h4>
        <ul class="plain" data-role="comparison-products">${productItems(products)}${formats}</ul>`;
    }
    const surveysHtml = ready.length
      ? ready
          .map(
            (s, i) => `<h4>${escapeHtml(s.name)} <span class="muted">${formatDate(s.captured_at, this.timeZone)}</span></h4>
              <ul class="plain" data-survey-products="${s.id}">${productItems(surveyProducts[i])}</ul>`,
          )
          .join("")
      : `<p class="muted">No ready survey yet.</p>`;
    this.box.innerHTML = `${comparisonHtml}${surveysHtml}
      <p class="muted">The report's PDF and HTML are under Reports.</p><p class="error" role="alert"></p>`;
  }

  get shown(): Comparison | null {
    return this.comparison;
  }
}
