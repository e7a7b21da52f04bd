// What can be said about the files before any byte is sent, in plain words.
// The server checks again, and fully, once they have arrived.

import { formatBytes } from "./format";
import { t } from "./i18n";

export interface FileLike {
  name: string;
  size: number;
}

const TIFF_MAGIC = ["49492a00", "4d4d002a", "49492b00", "4d4d002b"];
export const SUFFIXES = {
  dsm: [".tif", ".tiff"],
  video: [".mp4", ".mov"],
  log: [".srt", ".csv", ".txt"],
  image: [".jpg", ".jpeg"],
} as const;
export const MIN_IMAGES = 3;

const hasSuffix = (name: string, suffixes: readonly string[]) =>
  suffixes.some((s) => name.toLowerCase().endsWith(s));

function sizeProblem(file: FileLike, maxBytes: number): string | null {
  if (file.size === 0) return t("check.empty", { file: file.name });
  if (file.size > maxBytes) return t("check.tooLarge", { file: file.name, size: formatBytes(file.size), max: formatBytes(maxBytes) });
  return null;
}

/** Problems with a DSM file; `head` is its first 4 bytes. */
export function checkDsmFile(file: FileLike, head: Uint8Array, maxBytes: number): string[] {
  const problems: string[] = [];
  if (!hasSuffix(file.name, SUFFIXES.dsm)) problems.push(t("check.notGeoTiff", { file: file.name }));
  const size = sizeProblem(file, maxBytes);
  if (size) problems.push(size);
  else if (!TIFF_MAGIC.includes(toHex(head.slice(0, 4))))
    problems.push(t("check.notTiffInside", { file: file.name }));
  return problems;
}

export function checkVideoSurvey(video: FileLike | null, log: FileLike | null, maxBytes: number): string[] {
  const problems: string[] = [];
  if (!video) problems.push(t("check.chooseVideo"));
  else if (!hasSuffix(video.name, SUFFIXES.video)) problems.push(t("check.notVideo", { file: video.name }));
  if (!log) problems.push(t("check.chooseLog"));
  else if (!hasSuffix(log.name, SUFFIXES.log)) problems.push(t("check.notLog", { file: log.name }));
  for (const file of [video, log]) {
    const size = file && sizeProblem(file, maxBytes);
    if (size) problems.push(size);
  }
  return problems;
}

export function checkImageSet(images: FileLike[], maxBytes: number): string[] {
  const problems: string[] = [];
  if (images.length < MIN_IMAGES) problems.push(t("check.tooFewPhotos", { min: MIN_IMAGES, count: images.length }));
  for (const image of images) {
    if (!hasSuffix(image.name, SUFFIXES.image)) problems.push(t("check.notJpeg", { file: image.name }));
    const size = sizeProblem(image, maxBytes);
    if (size) problems.push(size);
  }
  const names = images.map((i) => i.name);
  const twice = names.filter((n, i) => names.indexOf(n) !== i);
  if (twice.length) problems.push(t("check.sameName", { names: [...new Set(twice)].join(", ") }));
  return problems;
}

/** The camera's readout time (a rolling shutter) as typed: empty is "not known";
 * otherwise milliseconds, at least 0 and under a second (the server checks it against
 * the video's frame length). Returns [problem, value]. */
export function checkReadoutMs(text: string): [string | null, number | null] {
  const trimmed = text.trim();
  if (!trimmed) return [null, null];
  const value = Number(trimmed);
  if (!Number.isFinite(value) || value < 0 || value >= 1000) return [t("check.readoutMs", { value: trimmed }), null];
  return [null, value];
}

export function checkCapturedAt(wall: string): string | null {
  if (!wall) return t("check.whenFlown");
  return null;
}

function toHex(bytes: Uint8Array): string {
  return Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
}
