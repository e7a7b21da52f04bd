import { expect, it } from "vitest";
import { sideClip, swipeClips } from "./swipe";

it("splits the view where the divider is, in layer pixels", () => {
  expect(swipeClips({ x: -100, y: 20 }, { x: 700, y: 620 }, 0.25)).toEqual({
    left: "rect(20px, 100px, 620px, -100px)",
    right: "rect(20px, 700px, 620px, 100px)",
  });
  expect(swipeClips({ x: 0, y: 0 }, { x: 10, y: 10 }, 2).left).toBe("rect(0px, 10px, 10px, 0px)");
});

it("clips an overlay to the side it is shown on, and not at all on both", () => {
  const clips = swipeClips({ x: 0, y: 0 }, { x: 800, y: 600 }, 0.5);
  expect(sideClip("left", clips)).toBe("rect(0px, 400px, 600px, 0px)");
  expect(sideClip("right", clips)).toBe("rect(0px, 800px, 600px, 400px)");
  expect(sideClip("both", clips)).toBe("");
});
