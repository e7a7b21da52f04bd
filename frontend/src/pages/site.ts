// A site's page: its surveys on a timeline, comparisons, processing, uploads, and the map.

import { ApiError, authHeaders, getJson, postJson } from "../api";
import { JobsPanel } from "../components/jobs";
import { renderTimeline } from "../components/timeline";
import { UploadPanel } from "../components/uploadPanel";
import { escapeHtml, formatArea, formatDate, formatMetres, formatVolume } from "../format";
import { MapView } from "../map/mapView";
import { detectionText, methodOptionsHtml, methodSummary } from "../methods";
import type {
  Comparison,
  ComparisonCreatedOut,
  DetectionFeature,
  DetectionMethod,
  Job,
  MapConfig,
  Site,
  Survey,
} from "../types";
import { comparisonWarningsHtml } from "../warnings";
import { header, wireSignOut } from "./header";

interface State {
  site: Site;
  surveys: Survey[];
  comparisons: Comparison[];
  shown: Comparison | null;
}

function comparisonLabel(c: Comparison, surveys: Survey[], timeZone: string): string {
  const name = (id: number) => {
    const s = surveys.find((x) => x.id === id);
    return s ? `${s.name} (${formatDate(s.captured_at, timeZone)})` : `survey ${id}`;
  };
  return `${name(c.pre_survey_id)} → ${name(c.post_survey_id)}`;
}

export async function renderSite(app: HTMLElement, siteId: number, config: MapConfig): Promise<() => void> {
  const site = await getJson<Site>(`sites/${siteId}`);
  app.innerHTML = `${header(`<a href="#/">Sites</a> <span aria-hidden="true">/</span> <span>${escapeHtml(site.name)}</span>`)}
    <main id="main" class="site-layout">
      <aside class="sidebar" aria-label="Site">
        <h1>${escapeHtml(site.name)}</h1>
        <p class="muted">Times in ${escapeHtml(site.timezone)}. ${escapeHtml(site.description)}</p>
        <section aria-labelledby="surveys-title"><h2 id="surveys-title">Surveys</h2><div id="surveys"></div></section>
        <section aria-labelledby="compare-title"><h2 id="compare-title">Compare two surveys</h2>
          <form id="compare-form" class="compare">
            <label for="pre-survey">Before (pre)</label><select id="pre-survey" required></select>
            <label for="post-survey">After (post)</label><select id="post-survey" required></select>
            <label for="method">Detection method</label>
            <select id="method" aria-describedby="method-summary"></select>
            <p class="muted method-summary" id="method-summary"></p>
            <button type="submit">Compare</button>
            <p class="error" role="alert" id="compare-error"></p>
          </form>
        </section>
        <section aria-labelledby="comparisons-title"><h2 id="comparisons-title">Comparisons</h2><ul id="comparisons" class="comparisons"></ul></section>
        <section aria-labelledby="jobs-title"><h2 id="jobs-title">Processing</h2><div id="jobs"></div></section>
        <section aria-labelledby="detections-title"><h2 id="detections-title">Detections</h2><div id="detections"></div>
          <p><a href="#" id="export-labels">Download verdicts as training labels (GeoJSON)</a></p></section>
        <section aria-labelledby="upload-title"><h2 id="upload-title">Upload a survey</h2><div id="upload"></div></section>
      </aside>
      <div class="map-wrap"><div id="map" role="region" aria-label="Map of ${escapeHtml(site.name)}" tabindex="0"></div></div>
    </main>`;
  wireSignOut(app);
  const $ = (id: string) => app.querySelector(`#${id}`) as HTMLElement;
  const map = new MapView($("map"), config);
  const state: State = { site, surveys: [], comparisons: [], shown: null };

  async function loadSurveys(): Promise<void> {
    state.surveys = await getJson<Survey[]>(`sites/${siteId}/surveys`);
    $("surveys").innerHTML = renderTimeline(state.surveys, site.timezone);
    const ready = state.surveys.filter((s) => s.status === "ready");
    const options = ready
      .map((s) => `<option value="${s.id}">${escapeHtml(s.name)} · ${formatDate(s.captured_at, site.timezone)}</option>`)
      .join("");
    for (const [id, pick] of [
      ["pre-survey", ready.at(-2)],
      ["post-survey", ready.at(-1)],
    ] as const) {
      const select = $(id) as HTMLSelectElement;
      const previous = select.value;
      select.innerHTML = options;
      select.value = previous && ready.some((s) => String(s.id) === previous) ? previous : String(pick?.id ?? "");
    }
    await map.showSurveys(site, state.surveys);
  }

  function renderComparisons(): void {
    $("comparisons").innerHTML = state.comparisons.length
      ? [...state.comparisons]
          .reverse()
          .map((c) => {
            const summary = c.summary
              ? `${c.summary.detections ?? 0} detections, ${formatArea(c.summary.total_area_m2)}, loss ${formatVolume(c.summary.total_volume_loss_m3)}`
              : escapeHtml(c.error ?? "");
            const current = state.shown?.id === c.id ? "aria-current=\"true\"" : "";
            const how = detectionText(c.detection);
            return `<li class="comparison status-${c.status}" data-comparison-id="${c.id}">
              <button type="button" data-show="${c.id}" ${current}>Show comparison ${c.id} on the map</button>
              <span>${escapeHtml(comparisonLabel(c, state.surveys, site.timezone))}</span>
              <span class="muted">${escapeHtml(c.method)} · <span class="comparison-status">${c.status}</span> · ${summary}</span>
              ${how ? `<span class="muted comparison-detection">${escapeHtml(how)}</span>` : ""}
              ${comparisonWarningsHtml(c.warnings)}</li>`;
          })
          .join("")
      : `<li class="muted">No comparison yet.</li>`;
  }

  function renderDetections(features: DetectionFeature[]): void {
    if (!state.shown) {
      $("detections").innerHTML = `<p class="muted">Show a finished comparison to see its detections.</p>`;
      return;
    }
    $("detections").innerHTML = features.length
      ? `<ol class="detections">${features
          .map(
            (f) => `<li><button type="button" data-detection="${f.id}">Detection ${f.id}</button>
              ${formatArea(f.properties.area_m2)}, max |Δh| ${formatMetres(f.properties.max_abs_dh_m)}, score ${f.properties.score.toFixed(2)}</li>`,
          )
          .join("")}</ol>`
      : `<p>No landslide found between these surveys.</p>`;
  }

  async function show(comparison: Comparison | null): Promise<void> {
    state.shown = comparison;
    renderComparisons();
    const pre = state.surveys.find((s) => s.id === comparison?.pre_survey_id) ?? state.surveys.at(-2) ?? null;
    const post = state.surveys.find((s) => s.id === comparison?.post_survey_id) ?? state.surveys.at(-1) ?? null;
    const features = await map.showPair({ pre, post, comparison });
    renderDetections(features);
  }

  async function loadComparisons(showLatest: boolean): Promise<void> {
    state.comparisons = await getJson<Comparison[]>(`sites/${siteId}/comparisons`);
    const latest = [...state.comparisons].reverse().find((c) => c.status === "succeeded") ?? null;
    if (showLatest || !state.shown) await show(latest);
    else renderComparisons();
  }

  // The methods and their default come from the API (the library's list), never from here.
  let methods: DetectionMethod[] = [];
  const methodSelect = $("method") as HTMLSelectElement;
  const showMethodSummary = () => {
    $("method-summary").textContent = methodSummary(methods, methodSelect.value);
  };
  async function loadMethods(): Promise<void> {
    try {
      methods = await getJson<DetectionMethod[]>("methods");
    } catch (e) {
      // Without the list the server still applies its default: the form sends no method.
      $("compare-error").textContent = `Detection methods unavailable: ${e instanceof ApiError ? e.message : "the server cannot be reached."}`;
      return;
    }
    methodSelect.innerHTML = methodOptionsHtml(methods);
    methodSelect.value = methods.find((m) => m.default)?.name ?? methods[0]?.name ?? "";
    showMethodSummary();
  }
  methodSelect.addEventListener("change", showMethodSummary);

  const jobs = new JobsPanel($("jobs"), siteId, site.timezone, (job: Job) => {
    void (async () => {
      await loadSurveys();
      await loadComparisons(job.kind === "comparison" && job.state === "succeeded");
    })();
  });

  $("comparisons").addEventListener("click", (event) => {
    const button = (event.target as HTMLElement).closest<HTMLButtonElement>("button[data-show]");
    const comparison = state.comparisons.find((c) => c.id === Number(button?.dataset.show));
    if (comparison) void show(comparison);
  });
  $("detections").addEventListener("click", (event) => {
    const button = (event.target as HTMLElement).closest<HTMLButtonElement>("button[data-detection]");
    if (button) map.openDetection(Number(button.dataset.detection));
  });
  ($("compare-form") as HTMLFormElement).addEventListener("submit", async (event) => {
    event.preventDefault();
    $("compare-error").textContent = "";
    try {
      const created = await postJson<ComparisonCreatedOut>(`sites/${siteId}/comparisons`, {
        pre_survey_id: Number(($("pre-survey") as HTMLSelectElement).value),
        post_survey_id: Number(($("post-survey") as HTMLSelectElement).value),
        method: methodSelect.value || null, // none chosen: the server's default
      });
      state.comparisons.push(created.comparison);
      renderComparisons();
      jobs.show([created.job]);
    } catch (e) {
      $("compare-error").textContent = e instanceof ApiError ? e.message : "The server cannot be reached.";
    }
  });
  $("export-labels").addEventListener("click", async (event) => {
    event.preventDefault();
    const response = await fetch(`/api/v1/sites/${siteId}/training-labels`, { headers: authHeaders() });
    const url = URL.createObjectURL(await response.blob());
    const link = document.createElement("a");
    link.href = url;
    link.download = `site-${siteId}-labels.geojson`;
    link.click();
    URL.revokeObjectURL(url);
  });

  new UploadPanel(
    $("upload"),
    site,
    config,
    () =>
      void (async () => {
        await loadSurveys();
        if (!state.shown) await show(null); // the newest two DSMs, until a comparison exists
      })(),
    (job) => jobs.show([job]),
  );
  await Promise.all([loadMethods(), loadSurveys()]);
  await loadComparisons(true);
  jobs.show(await getJson<Job[]>(`sites/${siteId}/jobs`));
  map.invalidateSize();
  return () => jobs.close();
}
