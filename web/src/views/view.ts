// What every page of the dashboard is given and provides.
import type { Api } from '../api';
import type { Store } from '../store';
import type { ColourMaps, ErrorEvent, FrameEvent, JobEvent } from '../types';

export interface Ctx {
  api: Api;
  store: Store;
  colourMaps: () => Promise<ColourMaps>;
  announce: (text: string) => void;
}

export interface View {
  readonly el: HTMLElement;
  readonly crumbs: { label: string; href: string }[];
  onFrame?(e: FrameEvent): void;
  onJob?(e: JobEvent): void;
  onError?(e: ErrorEvent): void;
  /** Reloads the page's data from REST (first load, and after the event stream reconnects). */
  resync(): Promise<void>;
  destroy(): void;
}
