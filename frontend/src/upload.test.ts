import { expect, it } from "vitest";
import { encodeMetadata } from "./upload";

it("encodes tus metadata as key and base64 of UTF-8, comma-separated", () => {
  const header = encodeMetadata({ filename: "Frana è.srt", survey_id: "12" });
  const [name, survey] = header.split(",");
  expect(name.split(" ")[0]).toBe("filename");
  const bytes = Uint8Array.from(atob(name.split(" ")[1]), (c) => c.charCodeAt(0));
  expect(new TextDecoder().decode(bytes)).toBe("Frana è.srt");
  expect(survey).toBe(`survey_id ${btoa("12")}`);
});
