"""Sequential visual SLAM for nadir drone video, in the spirit of DSO's design choices.

Frames are processed as a stream (`VisualSlam.process`), so reconstruction can start
while a video is still arriving: KLT tracking on every frame, camera pose by PnP on the
tracked map points, keyframes by parallax and track survival, triangulation of new
points, windowed bundle adjustment (pycolmap/Ceres with the older keyframes fixed), a new
map segment when tracking is lost (segments are tied together by georeferencing), and
SGBM densification of rectified keyframe pairs as keyframes leave the window.

Modules: `tracker` (KLT with ids), `geometry` (poses, triangulation), `bundle`
(windowed and pose-prior bundle adjustment), `densify` (SGBM), `system` (the loop),
`result` (what a run produces, saved and loaded as one .npz).
"""
