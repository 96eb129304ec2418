// The daemon's JSON forms the dashboard reads (docs/api.md). Fields the farm-integration work adds
// (converged, estimated_error.relmse/equivalent_spp...) are optional: shown when present.

export interface Job {
  id: string;
  name: string;
  state: 'active' | 'paused';
  created: string;
  renderer?: string;
  spp?: number;
  watch?: { dir: string; pattern: string };
  output: { dir: string; formats?: string[] };
  pipeline?: { denoiser: string; mixer: string };
}

export interface EstimatedError {
  mse: number;
  source?: string;
  // With the farm integration's calibrated estimate: 95 % intervals (null = unbounded).
  mse_low?: number | null;
  mse_high?: number | null;
  relmse?: number;
  relmse_low?: number | null;
  relmse_high?: number | null;
  equivalent_spp?: number;
  equivalent_spp_low?: number | null;
  equivalent_spp_high?: number | null;
  [key: string]: unknown;
}

export interface FrameStatus {
  job: string;
  frame: number;
  passes: number;
  spp: number;
  version: number;
  updated: string | null;
  estimated_mse: number;
  estimated_error?: EstimatedError;
  pending: boolean;
  converged?: boolean;
  versions?: number[]; // the versions the daemon keeps images of (farm integration), newest first
}

/** One published version of a frame (GET .../history, and the `frame` event). */
export interface Version {
  version: number;
  updated: string;
  passes: number;
  spp: number;
  estimated_mse: number;
  estimated_error?: EstimatedError;
  render_mse?: number;
  converged?: boolean;
}

export interface FrameEvent extends Version {
  job: string;
  name: string;
  frame: number;
  new_passes: number;
  outputs?: string[];
}

export interface JobEvent {
  job: string;
  name: string;
  state: 'created' | 'paused' | 'resumed' | 'deleted' | string;
}

export interface ErrorEvent {
  job: string;
  frame: number;
  pass: string;
  path: string;
  kind: string;
  message: string;
  quarantined: boolean;
}

export interface QuarantineRecord {
  frame: number;
  pass: string;
  path: string;
  kind: string;
  message: string;
  time: string;
}

export interface ColourMaps {
  colormaps: Record<string, string[]>;
  layers: Record<string, { kind: 'colour' | 'scalar'; colormap?: string; scale?: 'linear' | 'log' }>;
}

/** The error estimate a version or frame reports: the calibrated object when present. */
export function errorOf(v: { estimated_mse: number; estimated_error?: EstimatedError }): number {
  const e = v.estimated_error?.mse;
  return typeof e === 'number' && Number.isFinite(e) ? e : v.estimated_mse;
}
