import { describe, expect, it } from "vitest";
import { checkDsmFile, checkImageSet, checkReadoutMs, checkVideoSurvey } from "./validation";

const TIFF = new Uint8Array([0x49, 0x49, 0x2a, 0x00]);
const PNG = new Uint8Array([0x89, 0x50, 0x4e, 0x47]);

describe("before the upload", () => {
  it("accepts a GeoTIFF", () => {
    expect(checkDsmFile({ name: "June.TIF", size: 1000 }, TIFF, 10_000)).toEqual([]);
  });

  it("says plainly what is wrong with a DSM", () => {
    expect(checkDsmFile({ name: "june.png", size: 1000 }, PNG, 10_000)).toEqual([
      "june.png is not a GeoTIFF: a DSM must be a .tif or .tiff file.",
      "june.png is not a TIFF file inside, whatever its name says.",
    ]);
    expect(checkDsmFile({ name: "big.tif", size: 25e9 }, TIFF, 20e9)[0]).toBe(
      "big.tif is 25 GB, more than the 20 GB this server accepts.",
    );
    expect(checkDsmFile({ name: "empty.tif", size: 0 }, new Uint8Array(), 10)).toEqual(["empty.tif is empty."]);
  });

  it("needs a video and its log", () => {
    expect(checkVideoSurvey({ name: "DJI_0001.MP4", size: 5 }, { name: "DJI_0001.SRT", size: 5 }, 100)).toEqual([]);
    expect(checkVideoSurvey(null, { name: "notes.docx", size: 5 }, 100)).toEqual([
      "Choose the video (.mp4 or .mov).",
      "notes.docx is not a flight log: use the .srt or .csv of the flight.",
    ]);
  });

  it("takes a camera's readout time in milliseconds, or none", () => {
    expect(checkReadoutMs("")).toEqual([null, null]);
    expect(checkReadoutMs(" 30 ")).toEqual([null, 30]);
    expect(checkReadoutMs("16.5")).toEqual([null, 16.5]);
    expect(checkReadoutMs("-2")[0]).toBe(
      "The camera's readout time is a number of milliseconds from 0 up to a frame's length (e.g. 30), not -2.",
    );
    expect(checkReadoutMs("fast")).toEqual([
      "The camera's readout time is a number of milliseconds from 0 up to a frame's length (e.g. 30), not fast.",
      null,
    ]);
  });

  it("needs three distinct photos", () => {
    const photo = (name: string) => ({ name, size: 10 });
    expect(checkImageSet([photo("a.jpg"), photo("b.jpg")], 100)).toEqual([
      "Choose at least 3 geotagged photos (2 chosen).",
    ]);
    expect(checkImageSet([photo("a.jpg"), photo("a.jpg"), photo("c.png")], 100)).toEqual([
      "c.png is not a JPEG photo.",
      "Two photos have the same name: a.jpg.",
    ]);
  });
});
