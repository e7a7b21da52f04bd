import { describe, expect, it } from "vitest";
import { popupClearance } from "./popupClearance";

// A phone: a 390 px wide map 523 px tall, 60 px below the page's top, in an 844 px window.
const map = { left: 0, top: 60, right: 390, bottom: 583 };
const view = { left: 0, top: 0, right: 390, bottom: 844 };

describe("popupClearance", () => {
  it("keeps the popup below the top controls and above the bottom ones", () => {
    const zoomAndTools = { left: 10, top: 70, right: 160, bottom: 210 }; // 150 px below the map's top
    const layers = { left: 300, top: 70, right: 380, bottom: 100 };
    const scaleAndCursor = { left: 200, top: 490, right: 380, bottom: 573 }; // from 93 px above its bottom
    const clearance = popupClearance(map, view, [zoomAndTools, layers, scaleAndCursor]);
    expect(clearance.topLeft).toEqual([8, 158]);
    expect(clearance.bottomRight).toEqual([8, 101]);
    // 523 - 150 - 93 - 16 of room, less the popup's tip and padding.
    expect(clearance.maxHeight).toBe(523 - 150 - 93 - 16 - 64);
  });

  it("counts the part of the map scrolled out of the window as covered", () => {
    const scrolled = { left: 0, top: -100, right: 390, bottom: 423 };
    expect(popupClearance(scrolled, view, []).topLeft).toEqual([8, 108]);
    const below = { left: 0, top: 500, right: 390, bottom: 1023 };
    expect(popupClearance(below, view, []).bottomRight).toEqual([8, 1023 - 844 + 8]);
  });

  it("leaves out an unfolded panel taller than half the map, and boxes outside it", () => {
    const panel = { left: 200, top: 70, right: 380, bottom: 400 };
    const elsewhere = { left: 0, top: 700, right: 390, bottom: 800 };
    expect(popupClearance(map, view, [panel, elsewhere]).topLeft).toEqual([8, 8]);
  });

  it("leaves out the controls beside the popup's columns", () => {
    const legend = { left: 10, top: 400, right: 330, bottom: 573 }; // a laptop's, bottom left
    expect(popupClearance(map, view, [legend], { left: 340, right: 380 }).bottomRight).toEqual([8, 8]);
    expect(popupClearance(map, view, [legend], { left: 200, right: 380 }).bottomRight).toEqual([8, 583 - 400 + 8]);
  });

  it("never asks for less than a readable popup", () => {
    const tall = { left: 0, top: 60, right: 390, bottom: 300 };
    const low = { left: 0, top: 350, right: 390, bottom: 583 };
    expect(popupClearance(map, view, [tall, low]).maxHeight).toBe(120);
  });
});
