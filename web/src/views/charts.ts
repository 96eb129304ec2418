// Accuracy charts (uPlot, log-log): one frame's estimated error per version against spp or wall
// time beside the plain render's, and a shot's spread across frames against spp.
import uPlot from 'uplot';
import 'uplot/dist/uPlot.min.css';
import { sci } from '../format';
import { frameSeries, type FrameAxis } from '../series';
import type { Spread } from '../store';
import type { Version } from '../types';

export type { FrameAxis };

const RESULT = '#4cc9f0';
const RENDER = '#f8961e';
const BAND = 'rgba(76, 201, 240, 0.18)';

function axisValues(_u: uPlot, vals: number[]): string[] {
  return vals.map((v) => (v === null || v === undefined ? '' : sci(v, 1)));
}

/** x ticks at the data's own spp levels (at most 8), which a log axis spanning less than a decade lacks. */
function dataSplits(u: uPlot): number[] {
  const xs = [...new Set((u.data[0] as number[]).filter((x) => x > 0))];
  const step = Math.ceil(xs.length / 8);
  return xs.filter((_, i) => i % step === 0 || i === xs.length - 1);
}

function logAxes(xLabel: string, xAtData: boolean): uPlot.Axis[] {
  const common = { stroke: '#c9d1d9', grid: { stroke: '#30363d', width: 1 }, ticks: { stroke: '#30363d' } };
  return [
    { ...common, label: xLabel, values: axisValues, ...(xAtData ? { splits: dataSplits, filter: (_u: uPlot, s: number[]) => s } : {}) },
    { ...common, label: 'estimated MSE', values: axisValues, size: 64 },
  ];
}

abstract class Chart {
  protected plot: uPlot | null = null;
  private resize: ResizeObserver;

  constructor(readonly host: HTMLElement) {
    this.resize = new ResizeObserver(() => {
      if (this.plot) this.plot.setSize(this.size());
    });
    this.resize.observe(host);
  }

  protected size(): { width: number; height: number } {
    return { width: Math.max(240, this.host.clientWidth), height: 260 };
  }

  destroy(): void {
    this.resize.disconnect();
    this.plot?.destroy();
  }
}

export class FrameChart extends Chart {
  points = 0; // versions drawn (tests read it through data-points)
  private interval = false; // the estimate comes with an interval (drawn as a band)

  update(versions: Version[], axis: FrameAxis, origin: number): void {
    const all = frameSeries(versions, axis, origin);
    const interval = all[3].some((v) => v !== null) || all[4].some((v) => v !== null);
    const data = interval ? all : all.slice(0, 3); // no interval: no band series at all
    this.points = data[0].length;
    this.host.dataset.points = String(this.points);
    const xLabel = axis === 'spp' ? 'samples per pixel' : 'wall time since the job started (s)';
    if (this.plot && this.plot.axes[0].label === xLabel && this.interval === interval) {
      this.plot.setData(data as uPlot.AlignedData);
      return;
    }
    this.interval = interval;
    this.plot?.destroy();
    this.plot = new uPlot(
      {
        ...this.size(),
        title: 'Estimated error per version',
        scales: { x: { distr: 3, log: 10 }, y: { distr: 3, log: 10 } },
        axes: logAxes(xLabel, axis === 'spp'),
        legend: { live: true },
        cursor: { drag: { x: false, y: false } },
        series: [
          { label: axis === 'spp' ? 'spp' : 'time (s)', value: (_u, v) => sci(v, 2) },
          {
            label: 'result (proden)',
            stroke: RESULT,
            width: 2,
            points: { show: true, size: 6 },
            value: (_u, v) => sci(v, 2),
          },
          {
            label: 'plain render (mean Var[x])',
            stroke: RENDER,
            width: 2,
            dash: [6, 4],
            points: { show: true, size: 5 },
            value: (_u, v) => sci(v, 2),
          },
          ...(interval
            ? [
                { label: '95 % low', stroke: RESULT, width: 0.5, value: (_u: uPlot, v: number) => sci(v, 2) },
                { label: '95 % high', stroke: RESULT, width: 0.5, value: (_u: uPlot, v: number) => sci(v, 2) },
              ]
            : []),
        ],
        bands: interval ? [{ series: [4, 3], fill: BAND }] : [],
      },
      data as uPlot.AlignedData,
      this.host,
    );
  }
}

export class ShotChart extends Chart {
  update(s: Spread): void {
    this.host.dataset.points = String(s.spp.length);
    const data = [s.spp, s.min, s.median, s.max, s.renderMedian] as uPlot.AlignedData;
    if (this.plot) {
      this.plot.setData(data);
      return;
    }
    this.plot = new uPlot(
      {
        ...this.size(),
        title: 'Shot: estimated error across frames',
        scales: { x: { distr: 3, log: 10 }, y: { distr: 3, log: 10 } },
        axes: logAxes('samples per pixel', true),
        cursor: { drag: { x: false, y: false } },
        bands: [{ series: [3, 1], fill: BAND }],
        series: [
          { label: 'spp', value: (_u, v) => sci(v, 2) },
          { label: 'min', stroke: RESULT, width: 1, value: (_u, v) => sci(v, 2) },
          { label: 'median (result)', stroke: RESULT, width: 2.5, points: { show: true }, value: (_u, v) => sci(v, 2) },
          { label: 'max', stroke: RESULT, width: 1, value: (_u, v) => sci(v, 2) },
          {
            label: 'median plain render',
            stroke: RENDER,
            width: 2,
            dash: [6, 4],
            value: (_u, v) => sci(v, 2),
          },
        ],
      },
      data,
      this.host,
    );
  }
}
