// Legends in metres for the colour layers, and the score ramp of detections.

import { cssGradient, legendPosition, ticks } from "../colormap";
import { scoreColor } from "../detections";
import { formatMetres, formatNumber } from "../format";
import { t } from "../i18n";

function scale(title: string, gradient: string, range: [number, number], id: string): HTMLElement {
  const [low, high] = range;
  const box = document.createElement("figure");
  box.className = "legend-scale";
  box.dataset.legend = id;
  box.innerHTML = `<figcaption>${title}</figcaption><div class="bar" style="background:${gradient}"></div><div class="ticks"></div>`;
  const tickBox = box.querySelector(".ticks") as HTMLElement;
  for (const value of ticks(low, high)) {
    const tick = document.createElement("span");
    tick.style.left = `${legendPosition(value, low, high) * 100}%`;
    tick.textContent = formatMetres(value, Math.abs(high - low) < 10 ? 1 : 0);
    tickBox.append(tick);
  }
  return box;
}

/** The elevation colours in metres; `layer` names the DSM when each has its own stretch,
 * `id` marks the legend (by default from the layer's name). */
export function elevationLegend(
  range: [number, number],
  layer?: string,
  id = layer ? `elevation-${layer.split(" ")[0].toLowerCase()}` : "elevation",
): HTMLElement {
  const title = layer ? t("legend.elevationOf", { layer }) : t("legend.elevation");
  return scale(title, cssGradient("terrain"), range, id);
}

export function differenceLegend(range: [number, number]): HTMLElement {
  const box = scale(t("legend.dh"), cssGradient("rdbu_r"), range, "dh");
  return box;
}

export function scoreLegend(): HTMLElement {
  const box = document.createElement("figure");
  box.className = "legend-scale";
  box.dataset.legend = "score";
  const stops = [0, 0.25, 0.5, 0.75, 1].map((s) => scoreColor(s)).join(", ");
  box.innerHTML = `<figcaption>${t("legend.score")}</figcaption><div class="bar" style="background:linear-gradient(to right, ${stops})"></div><div class="ticks"><span style="left:0%">0</span><span style="left:50%">${formatNumber(0.5)}</span><span style="left:100%">1</span></div>`;
  return box;
}
