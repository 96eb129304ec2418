// Chart data from a frame's versions (pure: the charts draw what this returns).
import { errorOf, type Version } from './types';

export type FrameAxis = 'spp' | 'time';

/**
 * A frame's chart data: x (spp, or seconds since `origin` ms), the result's estimated error, the
 * plain render's, and the estimate's 95 % interval where the daemon gives one (else nulls).
 */
export function frameSeries(versions: Version[], axis: FrameAxis, origin: number): (number | null)[][] {
  const rows: (number | null)[][] = [];
  const pos = (v: unknown) => (typeof v === 'number' && v > 0 ? v : null);
  for (const v of versions) {
    const xv = axis === 'spp' ? v.spp : (Date.parse(v.updated) - origin) / 1000;
    if (!(xv > 0)) continue;
    const ee = v.estimated_error;
    rows.push([xv, pos(errorOf(v)), pos(v.render_mse), pos(ee?.mse_low), pos(ee?.mse_high)]);
  }
  // uPlot needs ascending x (wall time is; spp may repeat when nothing was added)
  rows.sort((a, b) => (a[0] as number) - (b[0] as number));
  return [0, 1, 2, 3, 4].map((k) => rows.map((r) => r[k]));
}
