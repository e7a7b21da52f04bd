import { describe, expect, it } from "vitest";
import { faststart, topLevelBoxes } from "./faststart";

function box(type: string, ...payload: Uint8Array[]): Uint8Array<ArrayBuffer> {
  const size = 8 + payload.reduce((n, p) => n + p.length, 0);
  const out = new Uint8Array(size);
  new DataView(out.buffer).setUint32(0, size);
  out.set([...type].map((c) => c.charCodeAt(0)), 4);
  let at = 8;
  for (const p of payload) {
    out.set(p, at);
    at += p.length;
  }
  return out;
}

function chunkOffsets(type: "stco" | "co64", offsets: number[]): Uint8Array<ArrayBuffer> {
  const width = type === "stco" ? 4 : 8;
  const body = new Uint8Array(8 + width * offsets.length);
  const view = new DataView(body.buffer);
  view.setUint32(4, offsets.length);
  offsets.forEach((o, i) => (type === "stco" ? view.setUint32(8 + 4 * i, o) : view.setBigUint64(8 + 8 * i, BigInt(o))));
  return box(type, body);
}

function track(type: "stco" | "co64", offsets: number[]): Uint8Array<ArrayBuffer> {
  const stbl = box("stbl", box("stsz", new Uint8Array(12)), chunkOffsets(type, offsets));
  return box("trak", box("tkhd", new Uint8Array(84)), box("mdia", box("minf", stbl)));
}

/** Media data whose chunks are marked with their number, so that an offset can be checked
 * by the bytes it points at. */
function mediaData(chunks: number, chunkBytes: number): Uint8Array<ArrayBuffer> {
  const data = new Uint8Array(chunks * chunkBytes);
  for (let i = 0; i < chunks; i++) data.fill(i + 1, i * chunkBytes, (i + 1) * chunkBytes);
  return box("mdat", data);
}

function concat(...parts: Uint8Array[]): Uint8Array<ArrayBuffer> {
  const out = new Uint8Array(parts.reduce((n, p) => n + p.length, 0));
  let at = 0;
  for (const p of parts) {
    out.set(p, at);
    at += p.length;
  }
  return out;
}

function offsetsIn(bytes: Uint8Array): number[] {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const found: number[] = [];
  for (const type of ["stco", "co64"]) {
    let at = -1;
    const marker = [...type].map((c) => c.charCodeAt(0));
    while ((at = bytes.findIndex((_, i) => i > at && marker.every((m, k) => bytes[i + k] === m))) >= 0) {
      const count = view.getUint32(at + 8);
      for (let i = 0; i < count; i++) {
        found.push(type === "stco" ? view.getUint32(at + 12 + 4 * i) : Number(view.getBigUint64(at + 12 + 8 * i)));
      }
    }
  }
  return found;
}

async function bytesOf(blob: Blob): Promise<Uint8Array<ArrayBuffer>> {
  return new Uint8Array(await blob.arrayBuffer());
}

const ftyp = box("ftyp", new TextEncoder().encode("isom\0\0\x02\0isomavc1"));

describe("index first (faststart)", () => {
  it("moves the index before the media and every chunk offset with the media", async () => {
    const mdat = mediaData(6, 100);
    const start = ftyp.length + 8; // first byte of media data
    const video = [0, 1, 2, 4].map((c) => start + 100 * c);
    const audio = [3, 5].map((c) => start + 100 * c);
    const moov = box("moov", box("mvhd", new Uint8Array(100)), track("stco", video), track("co64", audio));
    const camera = concat(ftyp, mdat, moov);
    const before = offsetsIn(camera).map((o) => camera[o]);
    expect(before).toEqual([1, 2, 3, 5, 4, 6]);

    const result = await faststart(new Blob([camera], { type: "video/mp4" }));
    const bytes = await bytesOf(result);
    expect(bytes.length).toBe(camera.length);
    expect(result.type).toBe("video/mp4");
    expect((await topLevelBoxes(result))?.map((b) => b.type)).toEqual(["ftyp", "moov", "mdat"]);
    const after = offsetsIn(bytes);
    expect(after).toEqual(offsetsIn(camera).map((o) => o + moov.length));
    expect(after.map((o) => bytes[o])).toEqual(before); // each offset still finds its chunk
    expect(bytes.slice(ftyp.length + moov.length)).toEqual(mdat);
  });

  it("keeps offsets into media that was already before the index", async () => {
    // ftyp, mdat A, moov, mdat B: only A moves (by the index's size); B stays where it was.
    const first = mediaData(2, 50);
    const second = mediaData(2, 50).map((v, i) => (i < 8 ? v : v + 10));
    const a = ftyp.length + 8;
    const placeholder = box("moov", track("stco", [0, 0, 0, 0]));
    const b = ftyp.length + first.length + placeholder.length + 8;
    const moov = box("moov", track("stco", [a, a + 50, b, b + 50]));
    const camera = concat(ftyp, first, moov, second);
    const bytes = await bytesOf(await faststart(new Blob([camera])));
    expect((await topLevelBoxes(new Blob([bytes])))?.map((t) => t.type)).toEqual(["ftyp", "moov", "mdat", "mdat"]);
    const after = offsetsIn(bytes);
    expect(after).toEqual([a + moov.length, a + 50 + moov.length, b, b + 50]);
    expect(after.map((o) => bytes[o])).toEqual([1, 2, 11, 12]);
  });

  it("leaves alone a file that is index-first already, or no MP4 at all", async () => {
    const ready = new Blob([concat(ftyp, box("moov", track("stco", [200])), mediaData(1, 10))]);
    expect(await faststart(ready)).toBe(ready);
    const text = new Blob([new TextEncoder().encode("not a video, just some text")]);
    expect(await faststart(text)).toBe(text);
    expect(await topLevelBoxes(text)).toBeNull();
    const cut = new Blob([concat(ftyp, mediaData(2, 100)).slice(0, 60)]);
    expect(await faststart(cut)).toBe(cut);
  });

  it("reads 64-bit box sizes", async () => {
    const data = new Uint8Array(40).fill(7);
    const large = new Uint8Array(16 + data.length);
    const view = new DataView(large.buffer);
    view.setUint32(0, 1);
    large.set([..."mdat"].map((c) => c.charCodeAt(0)), 4);
    view.setBigUint64(8, BigInt(large.length));
    large.set(data, 16);
    const moov = box("moov", track("stco", [ftyp.length + 16]));
    const bytes = await bytesOf(await faststart(new Blob([concat(ftyp, large, moov)])));
    const [offset] = offsetsIn(bytes);
    expect(offset).toBe(ftyp.length + moov.length + 16);
    expect(bytes[offset]).toBe(7);
  });
});
