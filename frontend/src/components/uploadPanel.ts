// Upload a survey: a DSM GeoTIFF, a video with its flight log, or a set of photos. Files go
// up resumably (tus); checked in plain words before they go and by the server after.

import { ApiError, getJson, postJson } from "../api";
import { escapeHtml, formatBytes, formatPercent, toZonedWallTime, zonedWallTimeToUtc } from "../format";
import { faststart } from "../faststart";
import type { Job, MapConfig, Site, Survey, SurveyFile } from "../types";
import { type RunningUpload, startUpload } from "../upload";
import { checkCapturedAt, checkDsmFile, checkImageSet, checkVideoSurvey } from "../validation";
import { fileWarningsHtml } from "../warnings";

type Kind = "dsm" | "video" | "images";

interface UploadStatus {
  state: "receiving" | "complete" | "failed";
  error: string | null;
  survey_id: number | null;
}

export class UploadPanel {
  private running: RunningUpload | null = null;
  private paused = false;
  private cancelled: ((error: Error) => void) | null = null;

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
        <fieldset class="kinds"><legend>What are you uploading?</legend>
          <label><input type="radio" name="kind" value="dsm" checked> DSM GeoTIFF</label>
          <label><input type="radio" name="kind" value="video"> Video + flight log</label>
          <label><input type="radio" name="kind" value="images"> Photos</label>
        </fieldset>
        <div data-kind="dsm">
          <label for="dsm-file">DSM (.tif, with its CRS)</label>
          <input id="dsm-file" type="file" accept=".tif,.tiff,image/tiff">
        </div>
        <div data-kind="video" hidden>
          <label for="video-file">Video (.mp4 or .mov)</label>
          <input id="video-file" type="file" accept=".mp4,.mov,video/*">
          <label for="log-file">Flight log (.srt or .csv)</label>
          <input id="log-file" type="file" accept=".srt,.csv,.txt">
        </div>
        <div data-kind="images" hidden>
          <label for="image-files">Geotagged photos (.jpg, at least 3)</label>
          <input id="image-files" type="file" accept=".jpg,.jpeg,image/jpeg" multiple>
        </div>
        <label for="survey-name">Survey name</label>
        <input id="survey-name" maxlength="200" placeholder="e.g. After the storm">
        <label for="captured-at">Flown at (time in ${escapeHtml(this.site.timezone)})</label>
        <input id="captured-at" type="datetime-local" value="${now}" required>
        <div class="buttons">
          <button type="submit" id="upload-start">Upload</button>
          <button type="button" id="upload-pause" disabled>Pause</button>
          <button type="button" id="upload-cancel" disabled>Cancel</button>
        </div>
        <label for="upload-progress" class="visually-hidden">Upload progress</label>
        <progress id="upload-progress" max="1" value="0" hidden></progress>
        <p id="upload-status" role="status" aria-live="polite"></p>
        <div id="upload-warnings" aria-live="polite"></div>
        <ul id="upload-errors" class="error" role="alert"></ul>
      </form>`;
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
      if (!file) problems.push("Choose the DSM file.");
      else problems.push(...checkDsmFile(file, new Uint8Array(await file.slice(0, 4).arrayBuffer()), max));
    } else if (kind === "video") {
      problems.push(...checkVideoSurvey(this.files("video-file")[0] ?? null, this.files("log-file")[0] ?? null, max));
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
    }
  }

  /** One file up, resolved when the server has checked and taken it. `onCreated` runs
   * once the server knows the upload; `body` is what is sent for the file. */
  private sendFile(
    file: File,
    metadata: Record<string, string>,
    label: string,
    onCreated?: () => Promise<void>,
    body: Blob = file,
  ): Promise<UploadStatus> {
    const progress = this.$("#upload-progress") as HTMLProgressElement;
    progress.hidden = false;
    return new Promise((resolve, reject) => {
      this.cancelled = reject;
      startUpload(file, metadata, this.config.upload_chunk_bytes, {
        onHashing: (f) => this.status(`Checking ${label} before sending: ${formatPercent(f)}`),
        onCreated: () => void onCreated?.().catch(reject),
        onResuming: (offset, total) =>
          this.status(`Resuming ${label}: ${formatBytes(offset)} of ${formatBytes(total)} were already sent.`),
        onProgress: (sent, total) => {
          progress.value = total ? sent / total : 0;
          this.status(`Uploading ${label}: ${formatBytes(sent)} of ${formatBytes(total)} (${formatPercent(sent / total)})`);
        },
        onRetry: (message) => this.status(message),
        onSuccess: async (url) => {
          this.status(`Checking ${label} on the server…`);
          try {
            resolve(await this.settled(url));
          } catch (e) {
            reject(e);
          }
        },
        onError: (reason) => reject(new Error(`${label} was not uploaded: ${reason}.`)),
      }, body)
        .then((running) => (this.running = running))
        .catch(reject);
    });
  }

  /** The upload's outcome (it may still be being checked after a resumed, finished upload). */
  private async settled(url: string): Promise<UploadStatus> {
    for (;;) {
      const status = await getJson<UploadStatus>(url);
      if (status.state === "failed") throw new Error(status.error ?? "the server refused the file");
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
    this.status(`${file.name} is now survey ${done.survey_id}, ready to compare.`);
    if (done.survey_id) this.onSurvey(done.survey_id);
  }

  /** A video + log or photo survey: the survey first, then its files (those not yet
   * there, so that a reload resumes), then the reconstruction job. A video survey is
   * processed while its video uploads: the log goes first, the video is sent with its
   * index first, and the job is queued as soon as the server knows the video's upload. */
  private async uploadSource(kind: "video" | "images", name: string, capturedAt: string): Promise<void> {
    const files =
      kind === "video"
        ? [
            { file: this.files("log-file")[0], role: "log" },
            { file: this.files("video-file")[0], role: "video" },
          ]
        : this.files("image-files").map((file) => ({ file, role: "image" }));
    const key = `slidewatch.source.${this.site.id}.${files.map((f) => `${f.file.name}-${f.file.size}`).join("+")}`;
    let survey: Survey | null = null;
    const known = localStorage.getItem(key);
    if (known) {
      survey = await getJson<Survey>(`sites/${this.site.id}/surveys/${known}`).catch(() => null);
      // A survey processed while its video uploads is "processing" (or "failed", if the
      // upload stalled): its video upload resumes too.
      const resumable = survey?.status === "receiving" || (kind === "video" && survey?.status !== "ready");
      if (!resumable) survey = null;
    }
    survey ??= await postJson<Survey>(`sites/${this.site.id}/surveys/sources`, {
      kind,
      name: name || files[0].file.name,
      captured_at: capturedAt,
    });
    localStorage.setItem(key, String(survey.id));
    this.onSurvey(survey.id);
    const id = survey.id;
    const listFiles = () => getJson<SurveyFile[]>(`sites/${this.site.id}/surveys/${id}/files`);
    const already = await listFiles();
    this.fileWarnings(already);
    const present = new Set(already.map((f) => f.name));
    let submitted = survey.status !== "receiving";
    const submit = async (): Promise<void> => {
      if (submitted) return;
      submitted = true;
      try {
        this.onJob(await postJson<Job>(`sites/${this.site.id}/surveys/${id}/process`, {}));
      } catch (e) {
        throw new Error(e instanceof ApiError ? e.message : String(e));
      }
    };
    for (const [i, { file, role }] of files.entries()) {
      if (present.has(file.name)) continue;
      const label = `${file.name} (${i + 1} of ${files.length})`;
      const metadata = { site_id: String(this.site.id), purpose: "survey_file", survey_id: String(id), role };
      if (role === "video") {
        this.status(`Preparing ${file.name} so that it is processed while it uploads…`);
        await this.sendFile(file, metadata, label, submit, await faststart(file));
      } else {
        await this.sendFile(file, metadata, label);
      }
      this.fileWarnings(await listFiles());
    }
    await submit();
    if (survey.status === "failed") await this.retryReconstruction(id);
    localStorage.removeItem(key);
    this.status(`All files are up; survey ${id} is being reconstructed.`);
  }

  /** A survey whose job failed while its video was arriving (the upload stalled): now that
   * the video is whole, its job runs again from the failed stage. */
  private async retryReconstruction(surveyId: number): Promise<void> {
    const jobs = await getJson<Job[]>(`sites/${this.site.id}/jobs`);
    const failed = jobs.find((j) => j.kind === "reconstruction" && j.survey_id === surveyId && j.state === "failed");
    if (failed) this.onJob(await postJson<Job>(`sites/${this.site.id}/jobs/${failed.id}/retry`, {}));
  }

  private async togglePause(): Promise<void> {
    if (!this.running) return;
    const button = this.$("#upload-pause") as HTMLButtonElement;
    if (this.paused) {
      this.running.resume();
      button.textContent = "Pause";
      this.status("Resuming…");
    } else {
      await this.running.pause();
      button.textContent = "Resume";
      this.status("Paused. Resume here, or later, even after closing the page: choose the same file again.");
    }
    this.paused = !this.paused;
  }

  private async cancel(): Promise<void> {
    await this.running?.cancel();
    this.running = null;
    this.cancelled?.(new Error("Upload cancelled; what was sent is deleted."));
    this.cancelled = null;
  }
}
