// People on the Account page: the members of each organisation this user manages (give a
// user a role, take it away) and, for the platform administrator, every user (create one,
// disable or enable one).

import { ApiError, api, getJson, postJson, putJson } from "../api";
import { escapeHtml, formatDateTime } from "../format";
import { type MessageKey, t } from "../i18n";
import { failure } from "./tools";

interface Organisation {
  id: number;
  name: string;
  role: string | null;
}

interface Member {
  username: string;
  display_name: string;
  role: string;
}

interface UserAccount {
  id: number;
  username: string;
  display_name: string;
  last_login_at: string | null;
  disabled_at: string | null;
}

const ROLES = ["viewer", "analyst", "manager", "admin"];
/** A role's name as the page says it (the API's own word in English). */
const roleName = (role: string) => (ROLES.includes(role) ? t(`role.${role}` as MessageKey) : role);
const roleOptions = (selected = "viewer") =>
  ROLES.map((r) => `<option value="${r}"${r === selected ? " selected" : ""}>${roleName(r)}</option>`).join("");

function membersHtml(org: Organisation, members: Member[]): string {
  const rows = members
    .map(
      (m) => `<tr><td>${escapeHtml(m.username)}</td><td>${escapeHtml(m.display_name)}</td><td>${escapeHtml(roleName(m.role))}</td>
        <td><button type="button" data-remove-member="${escapeHtml(m.username)}" data-org="${org.id}"
          aria-label="${escapeHtml(t("people.removeNamed", { user: m.username, organisation: org.name }))}">${t("people.remove")}</button></td></tr>`,
    )
    .join("");
  return `<h3>${escapeHtml(org.name)}</h3>
    <table class="members"><tbody>${rows}</tbody></table>
    <form data-add-member="${org.id}">
      <label for="member-name-${org.id}">${t("people.giveRole", { organisation: escapeHtml(org.name) })}</label>
      <input id="member-name-${org.id}" name="username" required maxlength="100" placeholder="${escapeHtml(t("people.userNamePlaceholder"))}">
      <select name="role" aria-label="${escapeHtml(t("people.role"))}">${roleOptions()}</select>
      <button type="submit">${t("people.addMember")}</button>
    </form>`;
}

function usersHtml(users: UserAccount[]): string {
  return `<table class="users"><tbody>${users
    .map(
      (u) => `<tr data-user="${u.id}"><td>${escapeHtml(u.username)}</td><td>${escapeHtml(u.display_name)}</td>
        <td class="muted">${u.disabled_at ? t("people.disabled") : t("people.lastSignIn", { when: escapeHtml(formatDateTime(u.last_login_at, "UTC")) })}</td>
        <td><button type="button" data-user-action="${u.disabled_at ? "enable" : "disable"}" data-id="${u.id}">${
          u.disabled_at ? t("people.enable") : t("people.disable")
        }</button></td></tr>`,
    )
    .join("")}</tbody></table>
    <form id="new-user">
      <label for="new-user-name">${t("people.newUserName")}</label><input id="new-user-name" required maxlength="100">
      <label for="new-user-display">${t("people.fullName")}</label><input id="new-user-display" maxlength="200">
      <label for="new-user-password">${t("people.newUserPassword")}</label>
      <input id="new-user-password" type="password" autocomplete="new-password" required>
      <button type="submit">${t("people.createUser")}</button>
    </form>`;
}

export class PeoplePanel {
  constructor(private readonly box: HTMLElement) {
    box.addEventListener("submit", (event) => {
      event.preventDefault();
      const form = event.target as HTMLFormElement;
      if (form.dataset.addMember) {
        const data = new FormData(form);
        void this.act(() =>
          putJson(`organisations/${form.dataset.addMember}/members/${encodeURIComponent(String(data.get("username")).trim())}`, {
            role: data.get("role"),
          }),
        );
      } else if (form.id === "new-user") {
        const value = (id: string) => (form.querySelector(`#${id}`) as HTMLInputElement).value;
        void this.act(() =>
          postJson("users", {
            username: value("new-user-name").trim(),
            display_name: value("new-user-display").trim(),
            password: value("new-user-password"),
          }),
        );
      }
    });
    box.addEventListener("click", (event) => {
      const target = event.target as HTMLElement;
      const member = target.closest<HTMLElement>("[data-remove-member]");
      if (member && window.confirm(t("people.confirmRemove", { user: member.dataset.removeMember ?? "" })))
        void this.act(() =>
          api(`organisations/${member.dataset.org}/members/${encodeURIComponent(member.dataset.removeMember ?? "")}`, {
            method: "DELETE",
          }),
        );
      const user = target.closest<HTMLElement>("[data-user-action]");
      if (user) void this.act(() => postJson(`users/${user.dataset.id}/${user.dataset.userAction}`, {}));
    });
  }

  private async act(action: () => Promise<unknown>): Promise<void> {
    const error = this.box.querySelector("#people-error") as HTMLElement | null;
    try {
      await action();
      await this.load();
    } catch (e) {
      if (error) error.textContent = failure(e);
    }
  }

  async load(): Promise<void> {
    const organisations = await getJson<Organisation[]>("organisations").catch(() => [] as Organisation[]);
    const managed = organisations.filter((o) => o.role === "manager" || o.role === "admin");
    const members = await Promise.all(managed.map((o) => getJson<Member[]>(`organisations/${o.id}/members`).catch(() => [])));
    // Only the platform administrator may list users: others are answered 403, and see none.
    const users = await getJson<UserAccount[]>("users").catch((e) => {
      if (e instanceof ApiError && e.status === 403) return null;
      throw e;
    });
    const parts = managed.map((o, i) => membersHtml(o, members[i]));
    if (users) parts.push(`<h3>${t("people.users")}</h3>${usersHtml(users)}`);
    this.box.innerHTML = parts.length
      ? `${parts.join("")}<p class="error" role="alert" id="people-error"></p>`
      : `<p class="muted">${t("people.managesNone")}</p>`;
  }
}
