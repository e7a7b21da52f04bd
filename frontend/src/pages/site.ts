// A site's page: its surveys on a timeline, comparisons, processing, uploads, and the map.

import { ApiError, api, authHeaders, getJson, postJson } from "../api";
import { AlertsPanel } from "../components/alerts";
import { DownloadsPanel } from "../components/downloads";
import { GisPanel } from "../components/gis";
import { JobsPanel } from "../components/jobs";
import { ReportsPanel } from "../components/reports";
import { SchedulesPanel } from "../components/schedules";
import { isTimeZone, timeZoneField } from "../components/tools";
import { renderTimeline } from "../components/timeline";
import { UploadPanel } from "../components/uploadPanel";
import { escapeHtml, formatArea, formatDate, formatFixed, formatMetres, formatVolume } from "../format";
import { type MessageKey, serverText, t } from "../i18n";
import { MapView } from "../map/mapView";
import { comparisonParameters, detectionText, methodOptionsHtml, methodSummary, MOWING_METHODS } from "../methods";
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

const JUMPS: Array<[string, MessageKey]> = [
  // Names that no other button's contains (tests and screen readers find buttons by name).
  ["upload-title", "site.jumpUpload"],
  ["compare-title", "site.jumpCompare"],
  ["detections-title", "site.jumpDetections"],
  ["tools-title", "site.jumpTools"],
];

const COMPARISON_STATES = new Set(["queued", "running", "succeeded", "failed"]);
/** A comparison's state in words; one the page does not know as the API says it. */
const stateWord = (state: string) => (COMPARISON_STATES.has(state) ? t(`state.${state}` as MessageKey) : state);

function comparisonLabel(c: Comparison, surveys: Survey[], timeZone: string): string {
  const name = (id: number) => {
    const s = surveys.find((x) => x.id === id);
    return s ? `${s.name} (${formatDate(s.captured_at, timeZone)})` : t("site.surveyNumbered", { id });
  };
  const pair = `${name(c.pre_survey_id)} → ${name(c.post_survey_id)}`;
  return c.name ? `${c.name}: ${pair}` : pair;
}

/** A rename asked for in the browser's own prompt; null when cancelled or unchanged. */
function askName(question: string, current: string): string | null {
  const name = window.prompt(question, current)?.trim();
  return name && name !== current ? name : null;
}

export async function renderSite(app: HTMLElement, siteId: number, config: MapConfig): Promise<() => void> {
  const site = await getJson<Site>(`sites/${siteId}`);
  const reportLanguages = await getJson<Array<{ code: string; name: string }>>("languages");
  app.innerHTML = `${header(`<a href="#/">${t("sites.title")}</a> <span aria-hidden="true">/</span> <span>${escapeHtml(site.name)}</span>`)}
    <main id="main" class="site-layout">
      <aside class="sidebar" aria-label="${escapeHtml(t("site.sidebar"))}">
        <h1>${escapeHtml(site.name)}</h1>
        <nav class="jump" aria-label="${escapeHtml(t("site.onThisPage"))}">${JUMPS.map(([id, label]) => `<button type="button" data-jump="${id}">${t(label)}</button>`).join("")}</nav>
        <p class="muted">${t("site.timesIn", { zone: `<span id="site-timezone">${escapeHtml(site.timezone)}</span>` })} ${escapeHtml(site.description)}</p>
        <p class="row-actions"><button type="button" id="rename-site">${t("site.rename")}</button>
          <button type="button" id="delete-site">${t("site.delete")}</button>
          <button type="button" id="change-timezone" aria-expanded="false">${t("site.changeTimeZone")}</button></p>
        <form id="timezone-form" class="tools" hidden>
          ${timeZoneField("timezone-input", site.timezone, t("site.timeZoneField"))}
          <label for="language-input">${t("site.reportLanguage")}</label>
          <select id="language-input">${reportLanguages
            .map((l) => `<option value="${escapeHtml(l.code)}" lang="${escapeHtml(l.code)}"${l.code === site.language ? " selected" : ""}>${escapeHtml(l.name)}</option>`)
            .join("")}</select>
          <button type="submit">${t("site.saveSiteSettings")}</button>
        </form>
        <p class="error" role="alert" id="manage-error"></p>
        <section aria-labelledby="surveys-title"><h2 id="surveys-title">${t("site.surveys")}</h2><div id="surveys"></div></section>
        <section aria-labelledby="compare-title"><h2 id="compare-title">${t("site.compareTitle")}</h2>
          <form id="compare-form" class="compare">
            <label for="pre-survey">${t("site.pre")}</label><select id="pre-survey" required></select>
            <label for="post-survey">${t("site.post")}</label><select id="post-survey" required></select>
            <label for="method">${t("site.method")}</label>
            <select id="method" aria-describedby="method-summary"></select>
            <p class="muted method-summary" id="method-summary"></p>
            <label class="check" id="vegetation-cut-row" hidden><input type="checkbox" id="vegetation-cut"> ${t("site.vegetationCut")}</label>
            <label class="check"><input type="checkbox" id="run-again"> ${t("site.runAgain")}</label>
            <button type="submit">${t("site.compare")}</button>
            <p class="muted" role="status" id="compare-status"></p>
            <p class="error" role="alert" id="compare-error"></p>
          </form>
        </section>
        <section aria-labelledby="comparisons-title"><h2 id="comparisons-title">${t("site.comparisons")}</h2><ul id="comparisons" class="comparisons"></ul></section>
        <section aria-labelledby="jobs-title"><h2 id="jobs-title">${t("site.processing")}</h2><div id="jobs"></div></section>
        <section aria-labelledby="detections-title"><h2 id="detections-title">${t("site.detections")}</h2><div id="detections"></div>
          <p><a href="#" id="export-labels">${t("site.exportLabels")}</a></p></section>
        <section aria-labelledby="tools-title" class="tools"><h2 id="tools-title">${t("site.tools")}</h2>
          <details id="reports-section"><summary>${t("site.reports")}</summary><div id="reports"></div></details>
          <details id="downloads-section"><summary>${t("site.downloads")}</summary><div id="downloads"></div></details>
          <details id="gis-section"><summary>${t("site.gis")}</summary><div id="gis"></div></details>
          <details id="schedules-section"><summary>${t("site.schedules")}</summary><div id="schedules"></div></details>
          <details id="alerts-section"><summary>${t("site.alerts")}</summary><div id="alerts"></div></details>
        </section>
        <section aria-labelledby="upload-title"><h2 id="upload-title">${t("site.upload")}</h2><div id="upload"></div></section>
      </aside>
      <div class="map-wrap"><div id="map" role="region" aria-label="${escapeHtml(t("site.mapOf", { name: site.name }))}" tabindex="0"></div></div>
    </main>`;
  wireSignOut(app);
  // Once the page is left (the site deleted, another page shown), late answers of requests
  // still in flight write into a detached element instead of failing on a missing one.
  const $ = (id: string) => (app.querySelector(`#${id}`) as HTMLElement | null) ?? document.createElement("div");
  const map = new MapView($("map"), config);
  // Jumps within the long sidebar (a phone stacks it under the map): buttons, since the
  // page's router owns the URL's #.
  app.querySelectorAll<HTMLButtonElement>("button[data-jump]").forEach((button) =>
    button.addEventListener("click", () => {
      const target = document.getElementById(button.dataset.jump ?? "");
      target?.setAttribute("tabindex", "-1");
      target?.scrollIntoView({ block: "start" });
      target?.focus({ preventScroll: true });
    }),
  );
  const state: State = { site, surveys: [], comparisons: [], shown: null };
  const reports = new ReportsPanel(
    $("reports"),
    siteId,
    site.timezone,
    reportLanguages.map((l) => l.code),
  );
  const downloads = new DownloadsPanel($("downloads"), siteId, site.timezone);
  const gis = new GisPanel($("gis"), siteId);
  const schedules = new SchedulesPanel($("schedules"), siteId, site.timezone);
  const alerts = new AlertsPanel($("alerts"), siteId, site.timezone);
  // Each panel asks the API when it is opened, not with the page: most visits open none.
  const onOpen: Array<[string, () => Promise<void>]> = [
    ["reports-section", () => reports.load()],
    ["downloads-section", () => downloads.show(state.surveys, state.shown)],
    ["gis-section", () => gis.load()],
    ["schedules-section", () => schedules.load()],
    ["alerts-section", () => alerts.load()],
  ];
  for (const [id, load] of onOpen) {
    $(id).addEventListener("toggle", () => {
      if (($(id) as HTMLDetailsElement).open) void load();
    });
  }
  $("change-timezone").addEventListener("click", () => {
    const form = $("timezone-form");
    form.hidden = !form.hidden;
    $("change-timezone").setAttribute("aria-expanded", String(!form.hidden));
  });
  $("timezone-form").addEventListener("submit", (event) => {
    event.preventDefault();
    void manage(async () => {
      const timezone = ($("timezone-input") as HTMLInputElement).value.trim();
      if (!isTimeZone(timezone)) throw new ApiError(422, t("site.notTimeZone", { zone: timezone }));
      const language = ($("language-input") as HTMLSelectElement).value;
      await api(`sites/${siteId}`, { method: "PATCH", body: JSON.stringify({ timezone, language }) });
      window.location.reload(); // every time on the page is shown anew in the new zone
    });
  });

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
              ? t("site.comparisonSummary", {
                  detections: t("count.detections", { count: c.summary.detections ?? 0 }),
                  area: formatArea(c.summary.total_area_m2),
                  loss: formatVolume(c.summary.total_volume_loss_m3),
                })
              : escapeHtml(c.error ? serverText(c.error) : "");
            const current = state.shown?.id === c.id ? "aria-current=\"true\"" : "";
            const how = detectionText(c.detection);
            return `<li class="comparison status-${c.status}" data-comparison-id="${c.id}">
              <button type="button" data-show="${c.id}" ${current}>${t("site.showComparison", { id: c.id })}</button>
              <span>${escapeHtml(comparisonLabel(c, state.surveys, site.timezone))}</span>
              <span class="muted">${escapeHtml(c.method)} · <span class="comparison-status">${stateWord(c.status)}</span> · ${summary}</span>
              ${how ? `<span class="muted comparison-detection">${escapeHtml(how)}</span>` : ""}
              ${comparisonWarningsHtml(c.warnings)}
              <span class="row-actions"><button type="button" data-rename-comparison="${c.id}">${t("site.renameComparison", { id: c.id })}</button>
                <button type="button" data-delete-comparison="${c.id}">${t("site.deleteComparison", { id: c.id })}</button></span></li>`;
          })
          .join("")
      : `<li class="muted">${t("site.noComparison")}</li>`;
  }

  function renderDetections(features: DetectionFeature[]): void {
    if (!state.shown) {
      $("detections").innerHTML = `<p class="muted">${t("site.showToSeeDetections")}</p>`;
      return;
    }
    $("detections").innerHTML = features.length
      ? `<ol class="detections">${features
          .map(
            // The label (1…n in this comparison) is the one the GeoJSON, the exports and
            // the report give; the database id only finds the polygon on the map.
            (f) => `<li><button type="button" data-detection="${f.id}">${t("popup.title", { label: f.properties.label ?? f.id })}</button>
              ${t("site.detectionLine", {
                area: formatArea(f.properties.area_m2),
                dh: formatMetres(f.properties.max_abs_dh_m),
                score: formatFixed(f.properties.score, 2),
              })}</li>`,
          )
          .join("")}</ol>`
      : `<p>${t("site.noLandslide")}</p>`;
  }

  async function show(comparison: Comparison | null): Promise<void> {
    state.shown = comparison;
    renderComparisons();
    // Without a comparison, the newest two ready DSMs: a survey that failed or is still
    // processing has none, and must not take the place of the site's ready one.
    const ready = state.surveys.filter((s) => s.status === "ready");
    const pre = state.surveys.find((s) => s.id === comparison?.pre_survey_id) ?? ready.at(-2) ?? null;
    const post = state.surveys.find((s) => s.id === comparison?.post_survey_id) ?? ready.at(-1) ?? null;
    const features = await map.showPair({ pre, post, comparison });
    renderDetections(features);
    reports.setComparison(comparison?.status === "succeeded" ? comparison.id : null);
    if (($("downloads-section") as HTMLDetailsElement).open) await downloads.show(state.surveys, comparison);
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
    // Only the LoD method can set mown grass aside.
    $("vegetation-cut-row").hidden = !MOWING_METHODS.includes(methodSelect.value);
  };
  async function loadMethods(): Promise<void> {
    try {
      methods = await getJson<DetectionMethod[]>("methods");
    } catch (e) {
      // Without the list the server still applies its default: the form sends no method.
      $("compare-error").textContent = t("site.methodsUnavailable", {
        reason: e instanceof ApiError ? e.message : t("site.unreachableLower"),
      });
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
    const target = event.target as HTMLElement;
    const renamed = state.comparisons.find((c) => c.id === Number(target.closest<HTMLElement>("[data-rename-comparison]")?.dataset.renameComparison));
    if (renamed) void manage(() => renameComparison(renamed));
    const deleted = state.comparisons.find((c) => c.id === Number(target.closest<HTMLElement>("[data-delete-comparison]")?.dataset.deleteComparison));
    if (deleted) void manage(() => deleteComparison(deleted));
  });
  $("surveys").addEventListener("click", (event) => {
    const target = event.target as HTMLElement;
    const of = (attribute: string) =>
      state.surveys.find((s) => s.id === Number(target.closest<HTMLElement>(`[data-${attribute}]`)?.getAttribute(`data-${attribute}`)));
    const renamed = of("rename-survey");
    if (renamed) void manage(() => renameSurvey(renamed));
    const deleted = of("delete-survey");
    if (deleted) void manage(() => deleteSurvey(deleted));
    const fixed = of("fix-survey");
    if (fixed) uploads.fixSurvey(fixed);
  });
  $("rename-site").addEventListener("click", () => void manage(renameSite));
  $("delete-site").addEventListener("click", () => void manage(deleteSite));

  /** Run a management action; its refusal (a role too small, a survey still in use) is said. */
  async function manage(action: () => Promise<void>): Promise<void> {
    $("manage-error").textContent = "";
    try {
      await action();
    } catch (e) {
      $("manage-error").textContent = e instanceof ApiError ? e.message : t("error.unreachable");
    }
  }

  async function renameSite(): Promise<void> {
    const name = askName(t("site.askSiteName", { name: site.name }), site.name);
    if (!name) return;
    await api(`sites/${siteId}`, { method: "PATCH", body: JSON.stringify({ name }) });
    window.location.reload();
  }

  async function deleteSite(): Promise<void> {
    const detections = state.comparisons.reduce((n, c) => n + (c.summary?.detections ?? 0), 0);
    const what = t("site.confirmDelete", {
      name: site.name,
      surveys: t("count.surveys", { count: state.surveys.length }),
      comparisons: t("count.comparisons", { count: state.comparisons.length }),
      detections: t("count.detections", { count: detections }),
    });
    if (!window.confirm(what)) return;
    await api(`sites/${siteId}`, { method: "DELETE" });
    window.location.hash = "#/";
  }

  async function renameSurvey(survey: Survey): Promise<void> {
    const name = askName(t("site.askSurveyName", { name: survey.name }), survey.name);
    if (!name) return;
    await api(`sites/${siteId}/surveys/${survey.id}`, { method: "PATCH", body: JSON.stringify({ name }) });
    await loadSurveys();
    renderComparisons();
  }

  async function deleteSurvey(survey: Survey): Promise<void> {
    const using = state.comparisons.filter((c) => c.pre_survey_id === survey.id || c.post_survey_id === survey.id);
    const question = t(survey.kind === "dsm" ? "site.confirmDeleteDsmSurvey" : "site.confirmDeleteSourceSurvey", {
      name: survey.name,
      also: using.length
        ? t("site.confirmDeleteSurveyAlso", {
            comparisons: t("count.comparisons", { count: using.length }),
            ids: using.map((c) => c.id).join(", "),
          })
        : "",
    });
    if (!window.confirm(question)) return;
    for (const c of using) await api(`sites/${siteId}/comparisons/${c.id}`, { method: "DELETE" });
    await api(`sites/${siteId}/surveys/${survey.id}`, { method: "DELETE" });
    if (state.shown && using.some((c) => c.id === state.shown?.id)) state.shown = null;
    await loadSurveys();
    await loadComparisons(!state.shown);
    await uploads.loadUnfinished();
  }

  async function renameComparison(comparison: Comparison): Promise<void> {
    const name = window.prompt(t("site.askComparisonName", { id: comparison.id }), comparison.name);
    if (name === null || name.trim() === comparison.name) return;
    await api(`sites/${siteId}/comparisons/${comparison.id}`, { method: "PATCH", body: JSON.stringify({ name: name.trim() }) });
    await loadComparisons(false);
  }

  async function deleteComparison(comparison: Comparison): Promise<void> {
    const found = comparison.summary?.detections ?? 0;
    const label = comparisonLabel(comparison, state.surveys, site.timezone);
    const what = t("site.confirmDeleteComparison", {
      id: comparison.id,
      label,
      detections: t("count.detections", { count: found }),
    });
    if (!window.confirm(what)) return;
    await api(`sites/${siteId}/comparisons/${comparison.id}`, { method: "DELETE" });
    const wasShown = state.shown?.id === comparison.id;
    if (wasShown) state.shown = null;
    await loadComparisons(wasShown);
  }
  $("detections").addEventListener("click", (event) => {
    const button = (event.target as HTMLElement).closest<HTMLButtonElement>("button[data-detection]");
    if (button) map.openDetection(Number(button.dataset.detection));
  });
  ($("compare-form") as HTMLFormElement).addEventListener("submit", async (event) => {
    event.preventDefault();
    $("compare-error").textContent = "";
    $("compare-status").textContent = "";
    const runAgain = $("run-again") as HTMLInputElement;
    try {
      const created = await postJson<ComparisonCreatedOut>(`sites/${siteId}/comparisons`, {
        pre_survey_id: Number(($("pre-survey") as HTMLSelectElement).value),
        post_survey_id: Number(($("post-survey") as HTMLSelectElement).value),
        method: methodSelect.value || null, // none chosen: the server's default
        parameters: comparisonParameters(methodSelect.value, ($("vegetation-cut") as HTMLInputElement).checked),
        run_again: runAgain.checked,
      });
      runAgain.checked = false;
      if (created.existing) {
        // Made before: opened rather than made again.
        const shown = state.comparisons.find((c) => c.id === created.comparison.id) ?? created.comparison;
        $("compare-status").textContent = t("site.alreadyCompared", {
          method: created.comparison.method,
          id: created.comparison.id,
        });
        await show(shown);
        return;
      }
      state.comparisons.push(created.comparison);
      renderComparisons();
      if (created.job) jobs.show([created.job]);
    } catch (e) {
      $("compare-error").textContent = e instanceof ApiError ? e.message : t("error.unreachable");
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

  const uploads = new UploadPanel(
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
  return () => {
    jobs.close();
    reports.close();
    alerts.close();
  };
}
