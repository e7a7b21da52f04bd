// What can be said about the files before any byte is sent, in plain words.
// The server checks again, and fully, once they have arrived.

import { formatBytes } from "./format";

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
  if (file.size === 0) return `${file.name} is empty.`;
  if (file.size > maxBytes)
    return `${file.name} is ${formatBytes(file.size)}, more than the ${formatBytes(maxBytes)} this server accepts.`;
  return null;
}

/** Problems with a DSM file; `head` is its first 4 bytes. */
export function checkDsmFile(file: FileLike, head: Uint8Array, maxBytes: number): string[] {
  const problems: string[] = [];
  if (!hasSuffix(file.name, SUFFIXES.dsm)) problems.push(`${file.name} is not a GeoTIFF: a DSM must be a .tif or .tiff file.`);
  const size = sizeProblem(file, maxBytes);
  if (size) problems.push(size);
  else if (!TIFF_MAGIC.includes(toHex(head.slice(0, 4))))
    problems.push(`${file.name} is not a TIFF file inside, whatever its name says.`);
  return problems;
}

export function checkVideoSurvey(video: FileLike | null, log: FileLike | null, maxBytes: number): string[] {
  const problems: string[] = [];
  if (!video) problems.push("Choose the video (.mp4 or .mov).");
  else if (!hasSuffix(video.name, SUFFIXES.video)) problems.push(`${video.name} is not a video slidewatch reads: use .mp4 or .mov.`);
  if (!log) problems.push("Choose the flight log (.srt from DJI, or a .csv log).");
  else if (!hasSuffix(log.name, SUFFIXES.log)) problems.push(`${log.name} is not a flight log: use the .srt or .csv of the flight.`);
  for (const file of [video, log]) {
    const size = file && sizeProblem(file, maxBytes);
    if (size) problems.push(size);
  }
  return problems;
}

export function checkImageSet(images: FileLike[], maxBytes: number): string[] {
  const problems: string[] = [];
  if (images.length < MIN_IMAGES) problems.push(`Choose at least ${MIN_IMAGES} geotagged photos (${images.length} chosen).`);
  for (const image of images) {
    if (!hasSuffix(image.name, SUFFIXES.image)) problems.push(`${image.name} is not a JPEG photo.`);
    const size = sizeProblem(image, maxBytes);
    if (size) problems.push(size);
  }
  const names = images.map((i) => i.name);
  const twice = names.filter((n, i) => names.indexOf(n) !== i);
  if (twice.length) problems.push(`Two photos have the same name: ${[...new Set(twice)].join(", ")}.`);
  return problems;
}

export function checkCapturedAt(wall: string): string | null {
  if (!wall) return "Say when the survey was flown.";
  return null;
}

function toHex(bytes: Uint8Array): string {
  return Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
}
