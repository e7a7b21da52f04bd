// "Use in GIS": the site's OGC API, XYZ, WMTS and STAC addresses, as the API gives them
// (no token in any), each with a copy button.

import { getJson } from "../api";
import { escapeHtml } from "../format";
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
    <button type="button" class="link-button" data-copy="${id}" aria-label="Copy ${escapeHtml(label)}">Copy</button></span>`;
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
          ? `Copied: ${field.value}`
          : "Copying is not allowed here: select the address and copy it by hand.";
      });
    });
  }

  async load(): Promise<void> {
    try {
      const links = await getJson<GisLinks>(`sites/${this.siteId}/gis`);
      const xyz = links.xyz.length
        ? links.xyz.map((layer, i) => row(`gis-xyz-${i}`, `XYZ tiles: ${layer.title}`, layer.template)).join("")
        : `<p class="muted">No map layer yet: upload a survey.</p>`;
      this.box.innerHTML = `<p class="muted">${escapeHtml(links.authentication)}</p>
        ${row("gis-ogc", "OGC API – Features (QGIS: Add WFS / OGC API layer)", links.ogc_api)}
        ${row("gis-ogc-detections", "This site's detections (OGC API items)", links.ogc_detections)}
        ${row("gis-wmts", "WMTS capabilities (every layer of the site)", links.wmts)}
        ${row("gis-stac", "STAC collection", links.stac)}
        ${xyz}
        <p class="muted" role="status" id="gis-status"></p>`;
    } catch (e) {
      this.box.innerHTML = `<p class="error" role="alert">${escapeHtml(failure(e))}</p>`;
    }
  }
}
