// A camera's MP4 with its index first, so that the server can decode the video while it
// uploads.
//
// Cameras write the `moov` box (the index: codec, frame sizes, where each chunk of media
// lies) after the media data (`mdat`), since they know it only when recording stops. A
// file uploaded that way can be decoded only once its last byte has arrived. `faststart`
// gives the same file with `moov` moved before the first `mdat`, as `ffmpeg -movflags
// faststart` does: every other box is kept byte for byte, and the chunk offsets in the
// index (`stco`, `co64`) are moved by as much as their box moved. Nothing is decoded or
// copied: the result is a Blob over slices of the original file plus the new index.

export interface Mp4Box {
  type: string;
  start: number;
  size: number;
}

const CONTAINERS = new Set(["moov", "trak", "mdia", "minf", "stbl"]);
const MAX_INDEX_BYTES = 512 * 1024 * 1024;

function boxType(view: DataView, at: number): string {
  return String.fromCharCode(view.getUint8(at), view.getUint8(at + 1), view.getUint8(at + 2), view.getUint8(at + 3));
}

/** (size, header length) of the box whose header starts at `at`; `end` for size 0. */
function boxSize(view: DataView, at: number, end: number): [number, number] {
  const size = view.getUint32(at);
  if (size === 1) return [Number(view.getBigUint64(at + 8)), 16];
  if (size === 0) return [end - at, 8];
  return [size, 8];
}

/** The top-level boxes of an MP4/MOV file, or null when it is not one (or is cut short). */
export async function topLevelBoxes(file: Blob): Promise<Mp4Box[] | null> {
  const boxes: Mp4Box[] = [];
  let at = 0;
  while (at < file.size) {
    if (file.size - at < 8) return null;
    const head = new DataView(await file.slice(at, at + 16).arrayBuffer());
    const type = boxType(head, 4);
    if (!/^[\x20-\x7e]{4}$/.test(type)) return null;
    const [size, header] = boxSize(head, 0, file.size - at);
    if (size < header || at + size > file.size) return null;
    boxes.push({ type, start: at, size });
    at += size;
  }
  return boxes.length ? boxes : null;
}

/** Move every chunk offset of the index (in place) by `moved(offset)`; false when an
 * offset no longer fits its 32-bit field. */
function moveChunkOffsets(view: DataView, start: number, end: number, moved: (offset: number) => number): boolean {
  let at = start;
  while (at + 8 <= end) {
    const [size, header] = boxSize(view, at, end);
    if (size < header || at + size > end) return true; // not ours to judge: left as it is
    const type = boxType(view, at + 4);
    if (CONTAINERS.has(type)) {
      if (!moveChunkOffsets(view, at + header, at + size, moved)) return false;
    } else if (type === "stco" || type === "co64") {
      const count = view.getUint32(at + header + 4);
      const first = at + header + 8;
      for (let i = 0; i < count; i++) {
        if (type === "stco") {
          const value = moved(view.getUint32(first + 4 * i));
          if (value > 0xffffffff) return false;
          view.setUint32(first + 4 * i, value);
        } else {
          const value = moved(Number(view.getBigUint64(first + 8 * i)));
          view.setBigUint64(first + 8 * i, BigInt(value));
        }
      }
    }
    at += size;
  }
  return true;
}

/** The file with its index before its media data (see the module comment); the file
 * itself when that is so already, or when it is not an MP4/MOV this can rearrange. */
export async function faststart(file: Blob): Promise<Blob> {
  const boxes = await topLevelBoxes(file);
  if (!boxes) return file;
  const moov = boxes.findIndex((b) => b.type === "moov");
  const mdat = boxes.findIndex((b) => b.type === "mdat");
  if (moov < 0 || mdat < 0 || moov < mdat || boxes[moov].size > MAX_INDEX_BYTES) return file;
  const order = [...boxes.slice(0, mdat), boxes[moov], ...boxes.slice(mdat).filter((b) => b.type !== "moov")];
  const shift = new Map<Mp4Box, number>();
  let at = 0;
  for (const box of order) {
    shift.set(box, at - box.start);
    at += box.size;
  }
  const moved = (offset: number): number => {
    const home = boxes.find((b) => offset >= b.start && offset < b.start + b.size);
    return home ? offset + (shift.get(home) ?? 0) : offset;
  };
  const index = boxes[moov];
  const bytes = await file.slice(index.start, index.start + index.size).arrayBuffer();
  const view = new DataView(bytes);
  const [, header] = boxSize(view, 0, index.size);
  if (!moveChunkOffsets(view, header, index.size, moved)) return file;
  const parts = order.map((b) => (b === index ? bytes : file.slice(b.start, b.start + b.size)));
  return new Blob(parts, { type: file.type });
}
