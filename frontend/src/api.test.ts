import { afterEach, describe, expect, it, vi } from "vitest";
import { ApiError, errorMessage, getJson, statusLead } from "./api";
import { t, useLocale } from "./i18n";
import { renderSignIn } from "./pages/signin";

afterEach(() => vi.unstubAllGlobals());

const taken = { detail: "A survey named 'May flight' exists already" };
const invalid = { detail: [{ loc: ["body", "captured_at"], msg: "Input should be a valid datetime" }] };

describe("an error of the API", () => {
  it("is the server's words alone on an English page", () => {
    expect(errorMessage(taken, 409)).toBe("A survey named 'May flight' exists already");
    expect(errorMessage(invalid, 422)).toBe("captured_at: Input should be a valid datetime");
    expect(errorMessage(null, 502)).toBe("the server answered 502");
  });

  it("leads with what kind of refusal it is in Japanese, the server's words after it", () => {
    useLocale("ja-JP");
    const conflict = errorMessage(taken, 409);
    expect(conflict.startsWith("現在の状態と矛盾するため実行できません。")).toBe(true);
    expect(conflict).toContain("A survey named 'May flight' exists already");
    expect(errorMessage(invalid, 422)).toBe(
      "入力に誤りがあります。サーバーからのメッセージ（英語）：captured_at: Input should be a valid datetime",
    );
    expect(errorMessage({ detail: "Bad range" }, 400)).toMatch(/^入力に誤りがあります。.*Bad range$/);
    expect(errorMessage({ detail: "Token expired" }, 401)).toMatch(/^認証が無効です。もう一度ログインしてください。.*Token expired$/);
    expect(errorMessage({ detail: "Managers only" }, 403)).toMatch(/^この操作を行う権限がありません。.*Managers only$/);
    expect(errorMessage({ detail: "No site 9" }, 404)).toMatch(/^対象が見つかりません。.*No site 9$/);
    expect(errorMessage({ detail: "Queue down" }, 503)).toMatch(/^サービスが一時的に利用できません。.*Queue down$/);
    expect(errorMessage({ detail: "Boom" }, 500)).toMatch(/^サーバーでエラーが発生しました。.*Boom$/);
    expect(errorMessage(null, 502)).toBe("サーバーでエラーが発生しました（HTTP 502）");
  });

  it("has a lead for every status, in every language", () => {
    for (const status of [400, 401, 403, 404, 409, 410, 412, 413, 415, 418, 422, 429, 460, 500, 503]) {
      expect(t(statusLead(status)).length).toBeGreaterThan(0);
    }
    expect(statusLead(460)).toBe("error.refused"); // tus's checksum mismatch: some other refusal
  });

  it("is what the page's requests throw", async () => {
    useLocale("ja-JP");
    vi.stubGlobal("fetch", async () => new Response(JSON.stringify({ detail: "No site 9" }), { status: 404 }));
    const error = await getJson("sites/9").catch((e: unknown) => e);
    expect(error).toBeInstanceOf(ApiError);
    expect((error as ApiError).status).toBe(404);
    expect((error as ApiError).message).toBe("対象が見つかりません。サーバーからのメッセージ（英語）：No site 9");
    expect((error as ApiError).detail).toBe("No site 9");
  });
});

describe("a refused sign-in in the page", () => {
  it("says the server's reason once, without the lead that asks to sign in again", async () => {
    useLocale("ja-JP");
    vi.stubGlobal(
      "fetch",
      async () => new Response(JSON.stringify({ detail: "wrong user name or password" }), { status: 401 }),
    );
    const app = document.createElement("div");
    renderSignIn(app, () => {});
    (app.querySelector("#username") as HTMLInputElement).value = "nina";
    (app.querySelector("#password") as HTMLInputElement).value = "a-wrong-guess";
    app.querySelector<HTMLFormElement>("#password-form")?.dispatchEvent(new Event("submit"));
    const error = app.querySelector("#password-error") as HTMLElement;
    await vi.waitFor(() => expect(error.textContent).not.toBe(""));
    expect(error.textContent).toContain("ログインできませんでした");
    expect(error.textContent).toContain("wrong user name or password");
    expect(error.textContent).not.toContain("もう一度ログインしてください");
  });
});
