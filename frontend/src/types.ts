// Shapes of the API's answers (backend/api/schemas.py, schemas_map.py).

export interface Site {
  id: number;
  name: string;
  description: string;
  area_of_interest: GeoJSON.Geometry | null;
  timezone: string;
  /** The language of its scheduled reports and alert e-mails (GET languages). */
  language: string;
  created_at: string;
}

export interface StoredFile {
  size_bytes: number;
  sha256: string;
  media_type: string;
  original_name: string | null;
}

export interface Survey {
  id: number;
  site_id: number;
  name: string;
  captured_at: string;
  kind: "dsm" | "video" | "images";
  status: "receiving" | "uploaded" | "processing" | "ready" | "failed";
  crs: string | null;
  footprint: GeoJSON.Geometry | null;
  resolution_m: number | null;
  source_file: StoredFile | null;
  error?: string | null;
  /** What reading its files and reconstructing it had to skip or assume, each once. */
  warnings: string[];
  /** The reconstruction's quality verdict; null before a report exists (and for a DSM). */
  quality: SurveyQuality | null;
  created_at: string;
}

/** Whether a reconstructed survey met the bounds its DSM is trusted by (SurveyOut.quality). */
export interface SurveyQuality {
  passed: boolean;
  checks: QualityCheck[];
}

/** One check of the verdict: the survey's figure, its bound and both in plain words. */
export interface QualityCheck {
  name: "georeference_accuracy" | "georeference_residual" | "overlap_coverage" | "segments_dropped" | "photo_outliers" | "georeference_shape" | "height_agreement" | "time_offset";
  value: number | null;
  bound: number | null;
  passed: boolean;
  message: string;
  /** The message as a catalogue key (`qualityText.<key>`) and its figures; absent on
   * checks made before the server recorded it. */
  text?: { key: string; figures: Record<string, string> } | null;
}

/** One uploaded input of a video or photo survey (GET …/surveys/{id}/files). */
export interface SurveyFile {
  id: number;
  survey_id: number;
  role: "video" | "log" | "image";
  name: string;
  file: StoredFile;
  /** What reading the file had to skip or assume, e.g. a log's unreadable blocks. */
  warnings: string[];
  created_at: string;
}

export interface Product {
  id: number;
  kind: string;
  survey_id: number | null;
  comparison_id: number | null;
  crs: string | null;
  file: StoredFile;
  download_url: string;
  created_at: string;
}

export type JobState = "queued" | "running" | "succeeded" | "failed";

export interface StageRun {
  stage: string;
  help: string; // what the stage does, in one line (declared with the stage in the library)
  state: "pending" | "running" | "succeeded" | "failed";
  progress: number;
  attempts: number;
  started_at: string | null;
  finished_at: string | null;
  error: string | null;
  result: Record<string, unknown> | null;
  /** What happened while it ran, over all its attempts: "HH:MM:SS LEVEL message" (UTC). */
  log: string[];
}

export interface Job {
  id: number;
  site_id: number;
  kind: string;
  comparison_id: number | null;
  survey_id: number | null;
  state: JobState;
  progress: number;
  error: string | null;
  created_at: string;
  started_at: string | null;
  finished_at: string | null;
  stages: StageRun[];
}

export interface Comparison {
  id: number;
  site_id: number;
  /** Given by people; empty: the page names it by its surveys. */
  name: string;
  pre_survey_id: number;
  post_survey_id: number;
  method: string;
  parameters: Record<string, unknown>;
  status: JobState;
  summary: {
    detections?: number;
    total_area_m2?: number;
    total_volume_loss_m3?: number;
    total_volume_gain_m3?: number;
    /** The co-registration's correction of the post DSM (after its rotation about the grid centre). */
    shift_m?: { east: number; north: number; up: number };
    rotation_deg?: number;
  } | null;
  error: string | null;
  created_at: string;
  finished_at: string | null;
  job_id: number | null;
  detection?: ComparisonDetection | null;
  /** Each quality check its pre- or post-event survey failed, naming the survey. */
  warnings: string[];
}

/** How a comparison detects (ComparisonOut.detection): LoD fields null until its
 * difference stage has run, model null for threshold (and for scored until it scored). */
export interface ComparisonDetection {
  method: string;
  lod_m: number | null;
  lod_p10_m: number | null;
  lod_p90_m: number | null;
  error_model: string | null;
  model: string | null;
}

/** One detection method (GET /api/v1/methods). */
export interface DetectionMethod {
  name: string;
  summary: string;
  stages: string[];
  default: boolean;
}

export interface FeedbackSummary {
  confirmed: number;
  false_alarm: number;
  latest: { verdict: Verdict; author: string; at: string } | null;
}

export type Verdict = "confirmed" | "false_alarm";

export interface DetectionProperties {
  comparison_id: number;
  /** 1…n within its comparison: the number the page, the exports and the report show. */
  label?: number;
  area_m2: number;
  volume_loss_m3: number;
  volume_gain_m3: number;
  max_abs_dh_m: number;
  score: number;
  method: string;
  model_version: string | null;
  /** 95 % intervals and the LoD over the polygon; null where the method has none (cnn). */
  uncertainty?: DetectionUncertainty | null;
  feedback: FeedbackSummary;
}

export interface DetectionUncertainty {
  area_m2_ci95?: [number, number];
  volume_loss_m3_ci95?: [number, number];
  volume_gain_m3_ci95?: [number, number];
  lod_m?: number;
}

export type DetectionFeature = GeoJSON.Feature<GeoJSON.Polygon | GeoJSON.MultiPolygon, DetectionProperties> & {
  id: number;
};

export interface TileJson {
  tiles: string[];
  bounds: [number, number, number, number];
  minzoom: number;
  maxzoom: number;
  colormap: string | null;
  rescale: [number, number] | null;
  unit: string;
}

export interface MapConfig {
  basemap_url: string | null;
  basemap_attribution: string;
  upload_chunk_bytes: number;
  max_upload_bytes: number;
  version: string;
}

export interface WhoAmI {
  kind: "user" | "token";
  name: string;
  expires_at: string | null;
}

export interface ComparisonCreatedOut {
  comparison: Comparison;
  job: Job | null;
  /** The same comparison was made before: it is answered, nothing new is queued. */
  existing: boolean;
}

/** A resumable upload as GET /sites/{id}/uploads lists the unfinished ones. */
export interface UnfinishedUpload {
  id: string;
  site_id: number;
  purpose: "dsm" | "survey_file";
  filename: string;
  length: number;
  offset: number;
  state: "receiving" | "complete" | "failed";
  survey_id: number | null;
  role: "video" | "log" | "image" | null;
  created_by: string;
  created_at: string;
}

/** An API token as GET /auth/tokens lists it (its secret is never listed). */
export type ApiTokenInfo = {
  id: number;
  name: string;
  prefix: string;
  kind: "session" | "api";
  created_at: string;
  last_used_at: string | null;
  expires_at: string | null;
  revoked_at: string | null;
  current: boolean;
};

export type NewApiToken = ApiTokenInfo & { token: string };
