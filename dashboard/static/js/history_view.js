// The History tab: every change of every job the filters select, with how long each job took,
// or every charge started and ended (its "show" switch), page by page, and the whole of it as a
// CSV file (the columns of `gridfleet job history --csv`, or of its `--charges --csv`).

import {
  chargeCells, chargeSummary, csvName, EXPORT_PAGE, historyCells, historyCsv, historyEntriesOf,
  historyQuery, historySummary, isHistoryEntry, stampText, TABLE_PAGE,
} from "./history.js";
import { PagedView } from "./paged_view.js";
import { JOB_STATES } from "./protocol_table.js";

export class HistoryView extends PagedView {
  /** `send` and `feedback` as PagedView's; `save(name, text)` hands a file to the browser. */
  constructor({ send, feedback, save = saveFile }) {
    super({
      name: "history", kind: "job_history", what: "job history",
      makeQuery: (fields, now, limit = TABLE_PAGE) => historyQuery(fields, now, limit),
      cells: (e, body) => (charges(body) ? chargeCells(e, stampText) : historyCells(e, stampText)),
      entriesOf: historyEntriesOf, valid: isHistoryEntry,
      send, feedback,
    });
    this.save = save;
    this.download = null; // {at}: a CSV is wanted once every page is in (asked at `at`, ms)
    const states = this.form.state;
    for (const s of JOB_STATES) states.append(new Option(s, s));
    document.querySelector("#history-csv").addEventListener("click", () => this.downloadCsv());
    // "show" while a download gathers pages: the person wants the table, not that file any more.
    this.form.addEventListener("submit", () => { this.download = null; });
    // Jobs or charges: the job and state filters are the jobs' only; the switch shows at once.
    this.form.kind.addEventListener("change", () => {
      this.filtersFor(this.form.kind.value);
      if (this.opened) { this.download = null; this.run(); }
    });
    this.filtersFor(this.form.kind.value);
  }

  /** The job and state filters offered only for the jobs. */
  filtersFor(kind) {
    for (const name of ["job", "state"]) this.form[name].disabled = kind === "charges";
  }

  /** A new query; the table's header and the words are those of its kind. */
  run(now = Date.now(), limit = undefined) {
    const before = this.what;
    this.what = this.form.kind.value === "charges" ? "charge history" : "job history";
    const body = super.run(now, limit);
    if (!body) { this.what = before; return null; }
    const table = this.tbody.closest("table");
    table.dataset.kind = body.kind;
    for (const tr of table.querySelectorAll("thead tr")) tr.hidden = tr.dataset.kind !== body.kind;
    return body;
  }

  decorate(tr, e) {
    tr.className = charges(this.query.body) ? `charge-${e.event}` : `job-${e.state}`;
  }

  /**
   * The CSV of what the filters select: the query shown when the filters are still its own (its
   * remaining pages fetched, the most at a time), else the filters' query afresh.
   */
  downloadCsv(now = Date.now()) {
    const q = historyQuery(this.fields(), now, EXPORT_PAGE);
    if (q.error) { this.feedback("history", "refused", q.error); return; }
    this.download = { at: now };
    const asShown = this.query.body && !this.query.error && JSON.stringify(this.fields()) === this.sentFields;
    if (!asShown) this.run(now, EXPORT_PAGE);
    this.feedback("history", "pending", "download CSV: fetching every page…");
    if (asShown && !this.query.busy) this.arrived();
  }

  arrived() {
    const body = this.query.body;
    const summary = charges(body) ? chargeSummary : historySummary;
    document.querySelector("#history-summary").textContent = summary(this.query.entries, this.query.next != null);
    if (!this.download) return;
    if (this.query.error) { this.download = null; return; }
    const things = charges(body) ? "charge entries" : "changes";
    if (this.more(EXPORT_PAGE)) { // the next page is on its way
      this.feedback("history", "pending", `download CSV: ${this.query.entries.length} ${things} so far…`);
      return;
    }
    if (this.query.busy) return;
    const entries = this.query.entries;
    this.save(csvName(body, this.download.at), historyCsv(entries, body.kind));
    this.download = null;
    this.feedback("history", "ok", `download CSV: ${entries.length} ${things} saved`);
  }

  gaveUp(reason) {
    this.download = null;
    super.gaveUp(reason);
  }
}

/** True when the query `body` asks for the charges rather than the jobs. */
function charges(body) {
  return body?.kind === "charges";
}

/** Hand `text` to the browser as a download named `name`. */
export function saveFile(name, text) {
  const url = URL.createObjectURL(new Blob([text], { type: "text/csv;charset=utf-8" }));
  const a = document.createElement("a");
  a.href = url;
  a.download = name;
  document.body.append(a);
  a.click();
  a.remove();
  // The browser has taken the file by the time a minute has passed; then the memory goes.
  setTimeout(() => URL.revokeObjectURL(url), 60000);
}
