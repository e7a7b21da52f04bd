"""Ingestion: flight logs, video, image sets and camera intrinsics, with plain-words errors.

- `flight_log`: the common `FlightLog` and `read_flight_log` (dispatch on content);
  the format families live in `srt` (DJI video subtitles; block structure in
  `srt_blocks`, joined recordings and the video's in `recordings`, camera settings in
  `srt_camera`) and `csv_logs` (AirData,
  PhantomHelp/TXTlogToCSV, Litchi and our documented generic CSV); `skipped` keeps
  unreadable records out and decides when too few remain to use a file.
- `video`: PyAV decoding with each frame's presentation time, as a stream.
- `images`: JPEG image sets with EXIF GPS/time and DJI XMP attitude.
- `camera`: intrinsics from EXIF, SRT hints and a table of drone cameras, overridable.
- `time_offset`: the offset between the video clock and the log clock, estimated.
"""
