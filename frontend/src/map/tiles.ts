// Tile layers of our own products. Tiles are fetched with the Authorization header (an <img>
// cannot send one, and a token in tile URLs would end up in access logs).

import L from "leaflet";
import { authHeaders, getJson } from "../api";
import { rescaleParam } from "../colormap";
import type { TileJson } from "../types";

export type Owner = { kind: "surveys" | "comparisons"; id: number };

export function layerBase(siteId: number, owner: Owner, layer: string): string {
  return `/api/v1/sites/${siteId}/${owner.kind}/${owner.id}/tiles/${layer}`;
}

export function tileJson(siteId: number, owner: Owner, layer: string): Promise<TileJson> {
  return getJson<TileJson>(`${layerBase(siteId, owner, layer)}/tilejson.json`);
}

export function tileTemplate(siteId: number, owner: Owner, layer: string, rescale?: [number, number]): string {
  const query = rescale ? `?rescale=${encodeURIComponent(rescaleParam(rescale))}` : "";
  return `${layerBase(siteId, owner, layer)}/{z}/{x}/{y}.png${query}`;
}

const AuthTileLayer = L.TileLayer.extend({
  createTile(this: L.TileLayer, coords: L.Coords, done: L.DoneCallback): HTMLElement {
    const img = document.createElement("img");
    img.alt = "";
    img.setAttribute("role", "presentation");
    fetch((this as unknown as { getTileUrl(c: L.Coords): string }).getTileUrl(coords), {
      headers: authHeaders(),
    })
      .then((response) => (response.ok ? response.blob() : null))
      .then((blob) => {
        if (!blob) return done(undefined, img); // outside the layer: an empty tile
        img.onload = () => {
          URL.revokeObjectURL(img.src);
          done(undefined, img);
        };
        img.onerror = () => done(new Error("tile did not decode"), img);
        img.src = URL.createObjectURL(blob);
      })
      .catch((error: Error) => done(error, img));
    return img;
  },
});

export function productTileLayer(template: string, info: TileJson, pane: string): L.TileLayer {
  const [west, south, east, north] = info.bounds;
  return new (AuthTileLayer as unknown as typeof L.TileLayer)(template, {
    pane,
    bounds: L.latLngBounds([south, west], [north, east]),
    minZoom: 0,
    maxZoom: 24,
    maxNativeZoom: info.maxzoom,
    tileSize: 256,
    keepBuffer: 1,
  });
}
