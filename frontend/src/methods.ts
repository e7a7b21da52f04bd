// The detection methods as the API lists them (GET /api/v1/methods), and how a comparison
// says it detected. The page has no list of its own: the library's is the only one, so
// the form's default is the API's and the CLI's.

import { escapeHtml, formatMetres, formatNumber } from "./format";
import { serverWords, t } from "./i18n";
import type { ComparisonDetection, DetectionMethod } from "./types";

/** The `<option>`s of the method `<select>`, the default one selected and labelled so. */
export function methodOptionsHtml(methods: DetectionMethod[]): string {
  return methods
    .map(
      (m) =>
        `<option value="${escapeHtml(m.name)}"${m.default ? " selected" : ""}>${escapeHtml(m.default ? t("methods.default", { name: m.name }) : m.name)}</option>`,
    )
    .join("");
}

/** The chosen method's one line, in the page's language (the server's words for a method
 * the catalogue does not know). */
export function methodSummary(methods: DetectionMethod[], name: string): string {
  const method = methods.find((m) => m.name === name);
  return method ? serverWords(`method.${method.name}`, method.summary) : "";
}

/** The methods that can set aside grass mown between surveys (the LoD method's
 * `vegetation_cut` option). */
export const MOWING_METHODS = ["threshold"];

/** The comparison's stage parameters for the form's choices: mown grass set aside only
 * where the method has the option and the user asked for it. */
export function comparisonParameters(method: string, setAsideMowing: boolean): Record<string, unknown> {
  return setAsideMowing && MOWING_METHODS.includes(method) ? { vectorize: { vegetation_cut: true } } : {};
}

/** "LoD 0.12 m (0.08–0.20 m, heteroscedastic) · model scorer-default@1": the level of
 * detection the comparison applied and the model behind its detections. Empty before
 * the difference stage has run and for a method without a model. */
export function detectionText(detection: ComparisonDetection | null | undefined): string {
  if (!detection) return "";
  const parts: string[] = [];
  if (detection.lod_m != null) {
    const spread =
      detection.lod_p10_m != null && detection.lod_p90_m != null
        ? `${formatNumber(detection.lod_p10_m)}–${formatMetres(detection.lod_p90_m)}`
        : null;
    const inside = [spread, detection.error_model].filter(Boolean).join(", ");
    parts.push(inside ? t("methods.lodWithin", { lod: formatMetres(detection.lod_m), inside }) : t("methods.lod", { lod: formatMetres(detection.lod_m) }));
  }
  if (detection.model) parts.push(t("methods.model", { model: detection.model }));
  return parts.join(" · ");
}
