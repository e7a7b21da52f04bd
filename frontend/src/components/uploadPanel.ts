// Upload a survey: a DSM GeoTIFF, a video with its flight log, or a set of photos. Files go
// up resumably (tus); checked in plain words before they go and by the server after.

import { api, getJson, postJson } from "../api";
import { escapeHtml, formatBytes, formatPercent, toZonedWallTime, zonedWallTimeToUtc } from "../format";
import { faststart } from "../faststart";
import { type MessageKey, serverText, t } from "../i18n";
import type { Job, MapConfig, Site, Survey, SurveyFile, UnfinishedUpload } from "../types";
import { cancelUpload, createUpload, forgetUpload, type RunningUpload, startUpload } from "../upload";
import { checkCapturedAt, checkDsmFile, checkImageSet, checkReadoutMs, checkVideoSurvey, MIN_IMAGES } from "../validation";
import { fileWarningsHtml } from "../warnings";

type Kind = "dsm" | "video" | "images";

interface UploadStatus {
  state: "receiving" | "complete" | "failed";
  error: string | null;
  survey_id: number | null;
}

const ROLE_WORDS: Record<string, MessageKey> = { video: "upload.roleVideo", log: "upload.roleLog", image: "upload.roleImage" };

/** Asks before the page is left while files are going up (the browser's own dialog). */
function holdPage(event: BeforeUnloadEvent): void {
  event.preventDefault();
  event.returnValue = ""; // older Chromium asks only when this is set
}

export class UploadPanel {
  private running: RunningUpload | null = null;
  private paused = false;
  private cancelled: ((error: Error) => void) | null = null;
  /** A failed survey whose files the next upload replaces (see fixSurvey). */
  private fixing: Survey | null = null;

  constructor(
    private readonly box: HTMLElement,
    private readonly site: Site,
    private readonly config: MapConfig,
    private readonly onSurvey: (surveyId: number) => void,
    private readonly onJob: (job: Job) => void,
  ) {
    this.render();
  }

  private $(selector: string): HTMLElement {
    return this.box.querySelector(selector) as HTMLElement;
  }

  private render(): void {
    const now = toZonedWallTime(new Date(), this.site.timezone);
    this.box.innerHTML = `
      <form id="upload-form" novalidate>
        <fieldset class="kinds"><legend>${t("upload.what")}</legend>
          <label><input type="radio" name="kind" value="dsm" checked> ${t("upload.kindDsm")}</label>
          <label><input type="radio" name="kind" value="video"> ${t("upload.kindVideo")}</label>
          <label><input type="radio" name="kind" value="images"> ${t("upload.kindImages")}</label>
        </fieldset>
        <div data-kind="dsm">
          <label for="dsm-file">${t("upload.dsmFile")}</label>
          <input id="dsm-file" type="file" accept=".tif,.tiff,image/tiff">
        </div>
        <div data-kind="video" hidden>
          <label for="video-file">${t("upload.videoFile")}</label>
          <input id="video-file" type="file" accept=".mp4,.mov,video/*">
          <label for="log-file">${t("upload.logFile")}</label>
          <input id="log-file" type="file" accept=".srt,.csv,.txt">
          <label for="readout-ms">${t("upload.readoutMs")}</label>
          <input id="readout-ms" type="number" min="0" step="0.1" inputmode="decimal">
        </div>
        <div data-kind="images" hidden>
          <label for="image-files">${t("upload.imageFiles", { min: MIN_IMAGES })}</label>
          <input id="image-files" type="file" accept=".jpg,.jpeg,image/jpeg" multiple>
        </div>
        <label for="survey-name">${t("upload.surveyName")}</label>
        <input id="survey-name" maxlength="200" placeholder="${escapeHtml(t("upload.surveyNamePlaceholder"))}">
        <label for="captured-at">${t("upload.flownAt", { zone: escapeHtml(this.site.timezone) })}</label>
        <input id="captured-at" type="datetime-local" value="${now}" required>
        <div class="buttons">
          <button type="submit" id="upload-start">${t("upload.start")}</button>
          <button type="button" id="upload-pause" disabled>${t("upload.pause")}</button>
          <button type="button" id="upload-cancel" disabled>${t("upload.cancel")}</button>
        </div>
        <label for="upload-progress" class="visually-hidden">${t("upload.progress")}</label>
        <progress id="upload-progress" max="1" value="0" hidden></progress>
        <p id="upload-status" role="status" aria-live="polite"></p>
        <div id="upload-warnings" aria-live="polite"></div>
        <ul id="upload-errors" class="error" role="alert"></ul>
      </form>
      <section id="unfinished" aria-labelledby="unfinished-title" hidden>
        <h3 id="unfinished-title">${t("upload.unfinished")}</h3>
        <p class="muted">${t("upload.unfinishedHelp")}</p>
        <ul id="unfinished-list" class="unfinished"></ul>
        <p id="unfinished-error" class="error" role="alert"></p>
      </section>`;
    const form = this.$("#upload-form") as HTMLFormElement;
    form.addEventListener("change", (event) => {
      if ((event.target as HTMLInputElement).name === "kind") this.showKind();
    });
    form.addEventListener("submit", (event) => {
      event.preventDefault();
      void this.start();
    });
    this.$("#upload-pause").addEventListener("click", () => void this.togglePause());
    this.$("#upload-cancel").addEventListener("click", () => void this.cancel());
    const list = this.$("#unfinished-list");
    list.addEventListener("change", (event) => {
      const input = event.target as HTMLInputElement;
      const upload = this.unfinished.find((u) => u.id === input.dataset.resume);
      const file = input.files?.[0];
      if (upload && file) void this.resumeUnfinished(upload, file);
    });
    list.addEventListener("click", (event) => {
      const button = (event.target as HTMLElement).closest<HTMLButtonElement>("button[data-cancel-upload]");
      const upload = this.unfinished.find((u) => u.id === button?.dataset.cancelUpload);
      if (upload) void this.cancelUnfinished(upload);
    });
    void this.loadUnfinished();
  }

  private unfinished: UnfinishedUpload[] = [];

  /** The site's uploads that stopped before their last byte (a reload, a closed laptop),
   * each to resume by choosing its file again, or to cancel. */
  async loadUnfinished(): Promise<void> {
    try {
      this.unfinished = await getJson<UnfinishedUpload[]>(`sites/${this.site.id}/uploads`);
    } catch {
      this.unfinished = []; // a viewer may not upload: nothing to resume
    }
    const shown = this.unfinished;
    this.$("#unfinished").hidden = shown.length === 0;
    this.$("#unfinished-list").innerHTML = shown
      .map((u) => {
        const role = u.role ? ROLE_WORDS[u.role] : undefined;
        const what = u.survey_id && role ? t("upload.fileOfSurvey", { role: t(role), id: u.survey_id }) : "DSM";
        return `<li data-upload-id="${escapeHtml(u.id)}"><span>${t("upload.unfinishedLine", {
          file: escapeHtml(u.filename),
          what,
          sent: formatBytes(u.offset),
          total: formatBytes(u.length),
        })}</span>
          <label>${t("upload.resumeNamed", { file: escapeHtml(u.filename) })} <input type="file" data-resume="${escapeHtml(u.id)}"></label>
          <button type="button" data-cancel-upload="${escapeHtml(u.id)}">${t("upload.cancelNamed", { file: escapeHtml(u.filename) })}</button></li>`;
      })
      .join("");
  }

  private async resumeUnfinished(upload: UnfinishedUpload, file: File): Promise<void> {
    this.$("#unfinished-error").textContent = "";
    // A video goes up with its index first: the same bytes as when it was started.
    const body = upload.role === "video" ? await faststart(file) : file;
    if (file.name !== upload.filename || body.size !== upload.length) {
      this.$("#unfinished-error").textContent =
        t("upload.wrongFile", { file: upload.filename, size: formatBytes(upload.length) });
      return;
    }
    this.busy(true);
    try {
      const url = `/api/v1/uploads/${upload.id}`;
      const done = await this.sendFile(file, {}, file.name, body, url);
      if (upload.purpose === "dsm") {
        this.status(t("upload.dsmDone", { file: file.name, id: done.survey_id ?? "" }));
        if (done.survey_id) this.onSurvey(done.survey_id);
      } else if (upload.survey_id) {
        await this.processIfComplete(upload.survey_id);
      }
    } catch (e) {
      this.errors([e instanceof Error ? e.message : String(e)]);
    } finally {
      this.running = null;
      this.busy(false);
      await this.loadUnfinished();
    }
  }

  /** After a resumed file: the survey is processed if it has all it needs and is not yet
   * (the server says what is missing otherwise). */
  private async processIfComplete(surveyId: number): Promise<void> {
    const survey = await getJson<Survey>(`sites/${this.site.id}/surveys/${surveyId}`);
    this.onSurvey(surveyId);
    if (survey.status !== "receiving" && survey.status !== "failed") {
      this.status(t("upload.allUpState", { id: surveyId, state: t(`survey.${survey.status}` as MessageKey) }));
      return;
    }
    try {
      this.onJob(await postJson<Job>(`sites/${this.site.id}/surveys/${surveyId}/process`, {}));
      this.status(t("upload.allUpReconstructing", { id: surveyId }));
    } catch (e) {
      this.status(t("upload.notProcessed", { id: surveyId, reason: e instanceof Error ? e.message : String(e) }));
    }
  }

  private async cancelUnfinished(upload: UnfinishedUpload): Promise<void> {
    const question = t("upload.confirmCancel", {
      file: upload.filename,
      sent: formatBytes(upload.offset),
      total: formatBytes(upload.length),
    });
    if (!window.confirm(question)) return;
    try {
      await cancelUpload(`/api/v1/uploads/${upload.id}`);
    } catch (e) {
      this.$("#unfinished-error").textContent = e instanceof Error ? e.message : String(e);
    }
    await this.loadUnfinished();
  }

  /** Fix a failed survey: the files chosen next replace its files of the same role, and
   * it is processed again (its failed job runs again from its first stage). */
  fixSurvey(survey: Survey): void {
    this.fixing = survey;
    const radio = this.box.querySelector<HTMLInputElement>(`input[name=kind][value="${survey.kind}"]`);
    if (radio) radio.checked = true;
    this.showKind();
    (this.$("#survey-name") as HTMLInputElement).value = survey.name;
    this.status(t("upload.fixing", { id: survey.id, name: survey.name }));
    this.box.scrollIntoView({ block: "nearest" });
  }

  private kind(): Kind {
    return (this.box.querySelector("input[name=kind]:checked") as HTMLInputElement).value as Kind;
  }

  private showKind(): void {
    const kind = this.kind();
    this.box.querySelectorAll<HTMLElement>("[data-kind]").forEach((el) => (el.hidden = el.dataset.kind !== kind));
  }

  private files(id: string): File[] {
    return Array.from((this.$(`#${id}`) as HTMLInputElement).files ?? []);
  }

  private status(text: string): void {
    this.$("#upload-status").textContent = text;
  }

  private errors(messages: string[]): void {
    this.$("#upload-errors").innerHTML = messages.map((m) => `<li>${escapeHtml(m)}</li>`).join("");
  }

  private busy(on: boolean): void {
    if (on) window.addEventListener("beforeunload", holdPage);
    else window.removeEventListener("beforeunload", holdPage);
    (this.$("#upload-start") as HTMLButtonElement).disabled = on;
    (this.$("#upload-pause") as HTMLButtonElement).disabled = !on;
    (this.$("#upload-cancel") as HTMLButtonElement).disabled = !on;
    this.$("#upload-progress").hidden = !on && (this.$("#upload-progress") as HTMLProgressElement).value === 0;
  }

  /** A notice under each file the server read with warnings (as it now reads them: a log
   * is read again when its video arrives). */
  private fileWarnings(files: SurveyFile[]): void {
    this.$("#upload-warnings").innerHTML = fileWarningsHtml(files);
  }

  private async start(): Promise<void> {
    this.errors([]);
    this.fileWarnings([]);
    const wall = (this.$("#captured-at") as HTMLInputElement).value;
    const problems: string[] = [];
    const when = checkCapturedAt(wall);
    if (when) problems.push(when);
    const kind = this.kind();
    const max = this.config.max_upload_bytes;
    if (kind === "dsm") {
      const [file] = this.files("dsm-file");
      if (!file) problems.push(t("check.chooseDsm"));
      else problems.push(...checkDsmFile(file, new Uint8Array(await file.slice(0, 4).arrayBuffer()), max));
    } else if (kind === "video") {
      problems.push(...checkVideoSurvey(this.files("video-file")[0] ?? null, this.files("log-file")[0] ?? null, max));
      const [readoutProblem] = checkReadoutMs((this.$("#readout-ms") as HTMLInputElement).value);
      if (readoutProblem) problems.push(readoutProblem);
    } else {
      problems.push(...checkImageSet(this.files("image-files"), max));
    }
    if (problems.length) {
      this.errors(problems);
      return;
    }
    const capturedAt = zonedWallTimeToUtc(wall, this.site.timezone).toISOString();
    const name = (this.$("#survey-name") as HTMLInputElement).value.trim();
    this.busy(true);
    try {
      if (kind === "dsm") await this.uploadDsm(this.files("dsm-file")[0], name, capturedAt);
      else await this.uploadSource(kind, name, capturedAt);
    } catch (e) {
      this.errors([e instanceof Error ? e.message : String(e)]);
      this.status("");
    } finally {
      this.running = null;
      this.busy(false);
      void this.loadUnfinished();
    }
  }

  /** One file up, resolved when the server has checked and taken it. `body` is what is
   * sent for the file; `uploadUrl`, the upload made for it already (createUpload). */
  private sendFile(
    file: File,
    metadata: Record<string, string>,
    label: string,
    body: Blob = file,
    uploadUrl: string | null = null,
  ): Promise<UploadStatus> {
    const progress = this.$("#upload-progress") as HTMLProgressElement;
    progress.hidden = false;
    return new Promise((resolve, reject) => {
      this.cancelled = reject;
      startUpload(file, metadata, this.config.upload_chunk_bytes, {
        onHashing: (f) => this.status(t("upload.hashing", { file: label, percent: formatPercent(f) })),
        onResuming: (offset, total) =>
          this.status(t("upload.resuming", { file: label, sent: formatBytes(offset), total: formatBytes(total) })),
        onProgress: (sent, total) => {
          progress.value = total ? sent / total : 0;
          this.status(
            t("upload.sending", { file: label, sent: formatBytes(sent), total: formatBytes(total), percent: formatPercent(sent / total) }),
          );
        },
        onRetry: (message) => this.status(message),
        onSuccess: async (url) => {
          this.status(t("upload.checkingOnServer", { file: label }));
          try {
            resolve(await this.settled(url || uploadUrl || ""));
          } catch (e) {
            reject(e);
          }
        },
        onError: (reason) => reject(new Error(t("upload.failed", { file: label, reason }))),
      }, body, uploadUrl)
        .then((running) => (this.running = running))
        .catch(reject);
    });
  }

  /** The upload's outcome (it may still be being checked after a resumed, finished upload). */
  private async settled(url: string): Promise<UploadStatus> {
    for (;;) {
      const status = await getJson<UploadStatus>(url);
      if (status.state === "failed") throw new Error(status.error ? serverText(status.error) : t("upload.refused"));
      if (status.state === "complete") return status;
      await new Promise((r) => setTimeout(r, 1000));
    }
  }

  private async uploadDsm(file: File, name: string, capturedAt: string): Promise<void> {
    const done = await this.sendFile(
      file,
      { site_id: String(this.site.id), purpose: "dsm", captured_at: capturedAt, name: name || file.name },
      file.name,
    );
    this.status(t("upload.dsmDone", { file: file.name, id: done.survey_id ?? "" }));
    if (done.survey_id) this.onSurvey(done.survey_id);
  }

  /** A video + log or photo survey: the survey first (or the failed survey being fixed),
   * then the server's upload of every file not yet there, made before anything is sent
   * or processed, so that processing never races the creation of an upload. Then the
   * files go up, the log first; a video survey is processed as soon as its log is in
   * (the server reads the video as it arrives: it is sent with its index first), a photo
   * survey once all photos are in. A reload resumes all of it. */
  private async uploadSource(kind: "video" | "images", name: string, capturedAt: string): Promise<void> {
    const files =
      kind === "video"
        ? [
            { file: this.files("log-file")[0], role: "log" },
            { file: this.files("video-file")[0], role: "video" },
          ]
        : this.files("image-files").map((file) => ({ file, role: "image" }));
    const key = `slidewatch.source.${this.site.id}.${files.map((f) => `${f.file.name}-${f.file.size}`).join("+")}`;
    let survey: Survey | null = this.fixing;
    const known = localStorage.getItem(key);
    if (!survey && known) {
      survey = await getJson<Survey>(`sites/${this.site.id}/surveys/${known}`).catch(() => null);
      // A survey processed while its video uploads is "processing" (or "failed", if the
      // upload stalled): its video upload resumes too.
      const resumable = survey?.status === "receiving" || (kind === "video" && survey?.status !== "ready");
      if (!resumable) survey = null;
    }
    // A rolling shutter's readout, where the user knows it: the slam method models it.
    const [, readoutMs] = kind === "video" ? checkReadoutMs((this.$("#readout-ms") as HTMLInputElement).value) : [null, null];
    survey ??= await postJson<Survey>(`sites/${this.site.id}/surveys/sources`, {
      kind,
      name: name || files[0].file.name,
      captured_at: capturedAt,
      ...(readoutMs === null ? {} : { options: { camera: { readout_ms: readoutMs } } }),
    });
    localStorage.setItem(key, String(survey.id));
    this.onSurvey(survey.id);
    const id = survey.id;
    const listFiles = () => getJson<SurveyFile[]>(`sites/${this.site.id}/surveys/${id}/files`);
    let already = await listFiles();
    if (this.fixing) {
      // Fixing: the survey's video or log gives way to the one chosen now (even of the
      // same name: a corrected file); photos chosen are added to its own.
      for (const old of already.filter((f) => f.role !== "image" && files.some((c) => c.role === f.role))) {
        await api<void>(`sites/${this.site.id}/surveys/${id}/files/${old.id}`, { method: "DELETE" });
      }
      already = await listFiles();
    }
    this.fileWarnings(already);
    const present = new Set(already.map((f) => f.name));
    const sending = [];
    for (const [i, { file, role }] of files.entries()) {
      if (present.has(file.name)) continue;
      const metadata = { site_id: String(this.site.id), purpose: "survey_file", survey_id: String(id), role };
      if (role === "video") this.status(t("upload.preparing", { file: file.name }));
      const body = role === "video" ? await faststart(file) : file;
      const url = await createUpload(file, metadata, body, (f) =>
        this.status(t("upload.hashing", { file: file.name, percent: formatPercent(f) })),
      );
      sending.push({ file, role, body, url, metadata, label: t("upload.fileOf", { file: file.name, n: i + 1, count: files.length }) });
    }
    let submitted = survey.status === "processing";
    const submit = async (): Promise<void> => {
      if (submitted) return;
      submitted = true;
      this.onJob(await postJson<Job>(`sites/${this.site.id}/surveys/${id}/process`, {}));
    };
    for (const item of sending.filter((f) => f.role !== "video")) {
      await this.sendFile(item.file, item.metadata, item.label, item.body, item.url);
      forgetUpload(item.file, item.metadata);
      this.fileWarnings(await listFiles());
    }
    // Every upload exists on the server and the log is in: the video may be read as it comes.
    if (kind === "video") await submit();
    for (const item of sending.filter((f) => f.role === "video")) {
      await this.sendFile(item.file, item.metadata, item.label, item.body, item.url);
      forgetUpload(item.file, item.metadata);
      this.fileWarnings(await listFiles());
    }
    await submit();
    // A survey whose job failed while its video was arriving (the upload stalled): now
    // that the video is whole, it is processed again from the failed stage.
    if (survey.status === "failed" && !this.fixing) await this.retryReconstruction(id);
    this.fixing = null;
    localStorage.removeItem(key);
    this.status(t("upload.allUpReconstructing", { id }));
    void this.loadUnfinished();
  }

  private async retryReconstruction(surveyId: number): Promise<void> {
    const current = await getJson<Survey>(`sites/${this.site.id}/surveys/${surveyId}`);
    if (current.status !== "failed") return;
    this.onJob(await postJson<Job>(`sites/${this.site.id}/surveys/${surveyId}/process`, {}));
  }

  private async togglePause(): Promise<void> {
    if (!this.running) return;
    const button = this.$("#upload-pause") as HTMLButtonElement;
    if (this.paused) {
      this.running.resume();
      button.textContent = t("upload.pause");
      this.status(t("upload.resumingNow"));
    } else {
      await this.running.pause();
      button.textContent = t("upload.resume");
      this.status(t("upload.paused"));
    }
    this.paused = !this.paused;
  }

  private async cancel(): Promise<void> {
    await this.running?.cancel();
    this.running = null;
    this.cancelled?.(new Error(t("upload.cancelled")));
    this.cancelled = null;
  }
}
