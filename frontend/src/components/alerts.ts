// Alerts of a site: when it alerts (thresholds), who gets e-mail (refused with the reason
// when the server cannot send any), webhooks with a test delivery, and the delivery log.

import { api, getJson, postJson, putJson } from "../api";
import { escapeHtml, formatDateTime } from "../format";
import { type MessageKey, t } from "../i18n";
import { failure } from "./tools";

interface AlertSettings {
  min_area_m2: number;
  min_volume_m3: number;
  min_score: number;
  email_recipients: string[];
  notify_job_failures: boolean;
  email_available: boolean;
  email_unavailable_reason: string | null;
}

interface Webhook {
  id: number;
  url: string;
  events: string[];
  description: string;
  active: boolean;
}

interface Delivery {
  id: number;
  channel: string;
  webhook_id: number | null;
  recipients: string[] | null;
  event: string;
  status: string;
  attempts: number;
  delivered_at: string | null;
  last_error: string | null;
  created_at: string;
}

const POLL_MS = 1500;

export function deliveryTarget(d: Delivery, webhooks: Webhook[]): string {
  if (d.channel === "email") return t("alerts.toEmail", { recipients: (d.recipients ?? []).join(", ") });
  const hook = webhooks.find((w) => w.id === d.webhook_id);
  return t("alerts.toWebhook", { target: hook ? hook.url : (d.webhook_id ?? t("alerts.deleted")) });
}

const DELIVERY_STATES = new Set(["pending", "retrying", "delivered", "failed"]);
/** A delivery's state in words; one the page does not know as the API says it. */
const deliveryState = (status: string) => (DELIVERY_STATES.has(status) ? t(`state.${status}` as MessageKey) : status);

export class AlertsPanel {
  private webhooks: Webhook[] = [];
  private timer: number | undefined;

  constructor(
    private readonly box: HTMLElement,
    private readonly siteId: number,
    private readonly timeZone: string,
  ) {
    box.innerHTML = `<form id="alert-form">
        <label for="alert-area">${t("alerts.minArea")}</label><input id="alert-area" type="number" min="0" step="any">
        <label for="alert-volume">${t("alerts.minVolume")}</label><input id="alert-volume" type="number" min="0" step="any">
        <label for="alert-score">${t("alerts.minScore")}</label><input id="alert-score" type="number" min="0" max="1" step="0.01">
        <label class="check"><input type="checkbox" id="alert-jobs"> ${t("alerts.jobFailures")}</label>
        <label for="alert-emails">${t("alerts.recipients")}</label><input id="alert-emails" autocomplete="off">
        <p class="muted" id="alert-email-reason"></p>
        <p class="row-actions"><button type="submit">${t("alerts.save")}</button>
          <button type="button" id="alert-test-email">${t("alerts.testEmail")}</button></p>
        <p class="muted" role="status" id="alert-status"></p>
        <p class="error" role="alert" id="alert-error"></p>
      </form>
      <h4>${t("alerts.webhooks")}</h4>
      <ul class="plain" id="webhook-list"></ul>
      <form id="webhook-form">
        <label for="webhook-url">${t("alerts.addWebhookLabel")}</label>
        <span class="inline"><input id="webhook-url" type="url" required maxlength="2048" placeholder="https://">
        <button type="submit">${t("alerts.addWebhook")}</button></span>
        <p class="notice" id="webhook-secret" hidden></p>
      </form>
      <h4>${t("alerts.log")}</h4>
      <table><thead><tr><th>${t("alerts.colWhen")}</th><th>${t("alerts.colEvent")}</th><th>${t("alerts.colTo")}</th><th>${t("alerts.colState")}</th></tr></thead>
        <tbody id="delivery-rows"></tbody></table>`;
    (box.querySelector("#alert-form") as HTMLFormElement).addEventListener("submit", (event) => {
      event.preventDefault();
      void this.act(() => this.saveSettings(), t("alerts.saved"));
    });
    box.querySelector("#alert-test-email")?.addEventListener("click", () =>
      void this.act(() => postJson(`sites/${siteId}/alerts/test-email`, {}), t("alerts.testEmailQueued")),
    );
    (box.querySelector("#webhook-form") as HTMLFormElement).addEventListener("submit", (event) => {
      event.preventDefault();
      void this.act(() => this.addWebhook(), t("alerts.webhookAdded"));
    });
    box.querySelector("#webhook-list")?.addEventListener("click", (event) => {
      const target = event.target as HTMLElement;
      const test = target.closest<HTMLElement>("[data-test-webhook]")?.dataset.testWebhook;
      const remove = target.closest<HTMLElement>("[data-delete-webhook]")?.dataset.deleteWebhook;
      if (test) void this.act(() => postJson(`sites/${siteId}/webhooks/${test}/test`, {}), t("alerts.testQueued"));
      if (remove && window.confirm(t("alerts.confirmDeleteWebhook")))
        void this.act(() => api(`sites/${siteId}/webhooks/${remove}`, { method: "DELETE" }), t("alerts.webhookDeleted"));
    });
  }

  private field(id: string): HTMLInputElement {
    return this.box.querySelector(`#${id}`) as HTMLInputElement;
  }

  private async act(action: () => Promise<unknown>, done: string): Promise<void> {
    this.field("alert-error").textContent = "";
    this.field("alert-status").textContent = "";
    try {
      await action();
      this.field("alert-status").textContent = done;
      await this.load();
    } catch (e) {
      this.field("alert-error").textContent = failure(e);
    }
  }

  private async saveSettings(): Promise<void> {
    const emails = this.field("alert-emails")
      .value.split(/[,;\s]+/)
      .filter(Boolean);
    await putJson(`sites/${this.siteId}/alerts`, {
      min_area_m2: Number(this.field("alert-area").value || 0),
      min_volume_m3: Number(this.field("alert-volume").value || 0),
      min_score: Number(this.field("alert-score").value || 0),
      notify_job_failures: this.field("alert-jobs").checked,
      email_recipients: emails,
    });
  }

  private async addWebhook(): Promise<void> {
    const made = await postJson<Webhook & { secret: string }>(`sites/${this.siteId}/webhooks`, {
      url: this.field("webhook-url").value.trim(),
    });
    this.field("webhook-url").value = "";
    const secret = this.field("webhook-secret");
    secret.hidden = false;
    secret.innerHTML = t("alerts.secret", { secret: `<code>${escapeHtml(made.secret)}</code>` });
  }

  async load(): Promise<void> {
    window.clearTimeout(this.timer);
    try {
      const [settings, webhooks] = await Promise.all([
        getJson<AlertSettings>(`sites/${this.siteId}/alerts`),
        getJson<Webhook[]>(`sites/${this.siteId}/webhooks`),
      ]);
      this.webhooks = webhooks;
      this.fill(settings);
      (this.box.querySelector("#webhook-list") as HTMLElement).innerHTML = webhooks.length
        ? webhooks
            .map(
              (w) => `<li data-webhook="${w.id}"><code class="url">${escapeHtml(w.url)}</code>
                <span class="muted">${w.active ? "" : `${t("alerts.inactive")} · `}${escapeHtml(w.events.join(", "))}</span>
                <span class="row-actions"><button type="button" data-test-webhook="${w.id}">${t("alerts.sendTest")}</button>
                <button type="button" data-delete-webhook="${w.id}">${t("alerts.delete")}</button></span></li>`,
            )
            .join("")
        : `<li class="muted">${t("alerts.noWebhook")}</li>`;
      await this.loadDeliveries();
    } catch (e) {
      this.field("alert-error").textContent = failure(e);
    }
  }

  private fill(s: AlertSettings): void {
    this.field("alert-area").value = String(s.min_area_m2);
    this.field("alert-volume").value = String(s.min_volume_m3);
    this.field("alert-score").value = String(s.min_score);
    this.field("alert-jobs").checked = s.notify_job_failures;
    const emails = this.field("alert-emails");
    emails.value = s.email_recipients.join(", ");
    // Without SMTP the server refuses recipients: say so before anyone types one.
    emails.disabled = !s.email_available && !s.email_recipients.length;
    (this.box.querySelector("#alert-test-email") as HTMLButtonElement).disabled = !s.email_available;
    const reason = s.email_unavailable_reason ?? t("alerts.emailUnavailable");
    this.field("alert-email-reason").textContent = s.email_available ? "" : `${reason[0].toUpperCase()}${reason.slice(1)}.`;
  }

  private async loadDeliveries(): Promise<void> {
    const deliveries = await getJson<Delivery[]>(`sites/${this.siteId}/deliveries?limit=20`);
    (this.box.querySelector("#delivery-rows") as HTMLElement).innerHTML = deliveries.length
      ? deliveries
          .map(
            (d) => `<tr data-delivery="${d.id}" data-status="${d.status}"><td>${escapeHtml(formatDateTime(d.created_at, this.timeZone))}</td>
              <td>${escapeHtml(d.event)}</td><td>${escapeHtml(deliveryTarget(d, this.webhooks))}</td>
              <td>${escapeHtml(t("alerts.stateLine", { state: deliveryState(d.status), attempts: t("count.attempts", { count: d.attempts }) }))}${
                d.last_error ? `: ${escapeHtml(d.last_error)}` : ""
              }</td></tr>`,
          )
          .join("")
      : `<tr><td colspan="4" class="muted">${t("alerts.nothingSent")}</td></tr>`;
    // Follow a delivery until it is delivered or given up.
    if (deliveries.some((d) => d.status === "pending" || d.status === "retrying")) {
      this.timer = window.setTimeout(() => void this.loadDeliveries().catch(() => {}), POLL_MS);
    }
  }

  close(): void {
    window.clearTimeout(this.timer);
  }
}
