// "Use in GIS": the site's OGC API, XYZ, WMTS and STAC addresses, as the API gives them
// (no token in any), each with a copy button.

import { getJson } from "../api";
import { escapeHtml } from "../format";
import { t } from "../i18n";
import { copyText, failure } from "./tools";

interface GisLinks {
  ogc_api: string;
  ogc_detections: string;
  wmts: string;
  stac: string;
  xyz: Array<{ title: string; template: string }>;
  authentication: string;
}

function row(id: string, label: string, url: string): string {
  return `<label for="${id}">${escapeHtml(label)}</label>
    <span class="inline"><input id="${id}" readonly value="${escapeHtml(url)}">
    <button type="button" class="link-button" data-copy="${id}" aria-label="${escapeHtml(t("gis.copyNamed", { label }))}">${t("gis.copy")}</button></span>`;
}

export class GisPanel {
  constructor(
    private readonly box: HTMLElement,
    private readonly siteId: number,
  ) {
    box.addEventListener("click", (event) => {
      const button = (event.target as HTMLElement).closest<HTMLButtonElement>("button[data-copy]");
      if (!button) return;
      const field = box.querySelector(`#${button.dataset.copy}`) as HTMLInputElement;
      void copyText(field.value, field).then((copied) => {
        (box.querySelector("#gis-status") as HTMLElement).textContent = copied
          ? t("gis.copied", { url: field.value })
          : t("gis.copyRefused");
      });
    });
  }

  async load(): Promise<void> {
    try {
      const links = await getJson<GisLinks>(`sites/${this.siteId}/gis`);
      const xyz = links.xyz.length
        ? links.xyz.map((layer, i) => row(`gis-xyz-${i}`, t("gis.xyz", { title: layer.title }), layer.template)).join("")
        : `<p class="muted">${t("gis.noLayer")}</p>`;
      this.box.innerHTML = `<p class="muted">${escapeHtml(links.authentication)}</p>
        ${row("gis-ogc", t("gis.ogc"), links.ogc_api)}
        ${row("gis-ogc-detections", t("gis.ogcDetections"), links.ogc_detections)}
        ${row("gis-wmts", t("gis.wmts"), links.wmts)}
        ${row("gis-stac", t("gis.stac"), links.stac)}
        ${xyz}
        <p class="muted" role="status" id="gis-status"></p>`;
    } catch (e) {
      this.box.innerHTML = `<p class="error" role="alert">${escapeHtml(failure(e))}</p>`;
    }
  }
}
