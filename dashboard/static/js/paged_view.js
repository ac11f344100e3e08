// A view of records the coordinator answers page by page (the History and Audit tabs): its
// filter form, its table and its "load more" button. The rows of a page are added once, when the
// page arrives: nothing here is redrawn for the fleet's messages, so a long table costs the page
// nothing while the fleet runs.

import { localInputValue } from "./history.js";
import { PagedQuery } from "./paging.js";

export class PagedView {
  /**
   * `name`: the view ("history", "audit"): its form `#<name>-form`, table `#<name>`, button
   * `#<name>-more` and feedback `#<name>-feedback`. `kind`: the request kind. `makeQuery(fields,
   * now)` → {body} or {error}; `cells(entry, body)` → [text, className] per cell of an entry of the
   * query `body`. `send(kind, form, what, body)` publishes a request and returns its id;
   * `feedback(form, kind, text)` shows words. `entriesOf` and `valid` as PagedQuery's.
   */
  constructor({ name, kind, what, makeQuery, cells, send, feedback, entriesOf, valid }) {
    this.name = name;
    this.kind = kind;
    this.what = what;
    this.makeQuery = makeQuery;
    this.cells = cells;
    this.send = send;
    this.feedback = feedback;
    this.query = new PagedQuery({ entriesOf, valid });
    this.opened = false;
    this.form = document.querySelector(`#${name}-form`);
    this.tbody = document.querySelector(`#${name} tbody`);
    this.moreButton = document.querySelector(`#${name}-more`);
    this.form.addEventListener("submit", (ev) => { ev.preventDefault(); this.run(); });
    this.form.addEventListener("input", () => this.feedback(name, "", "")); // its words are stale
    this.moreButton.addEventListener("click", () => this.more());
  }

  /** The tab is shown: the first time, the last day's records are asked for. */
  open(now = Date.now()) {
    if (this.opened) return;
    this.opened = true;
    if (!this.form.since.value) this.form.since.value = localInputValue(now - 24 * 3600 * 1000);
    this.run(now);
  }

  /** The filters' text, by field name. */
  fields() {
    return Object.fromEntries([...this.form.elements].filter((el) => el.name).map((el) => [el.name, el.value]));
  }

  /** A new query from the filters: a mistake is told at once and nothing is sent. */
  run(now = Date.now(), limit = undefined) {
    const q = this.makeQuery(this.fields(), now, limit);
    if (q.error) { this.feedback(this.name, "refused", q.error); return null; }
    const body = this.query.begin(q.body);
    this.sentFields = JSON.stringify(this.fields()); // what the query shown was made of
    this.tbody.replaceChildren();
    this.shown = 0;
    this.query.sent(this.send(this.kind, this.name, this.what, body));
    this.feedback(this.name, "pending", `${this.what}: asking the coordinator…`);
    this.update();
    return body;
  }

  /** The next page of the query shown, if there is one. */
  more(limit = undefined) {
    const body = this.query.more(limit);
    if (!body) return false;
    this.query.sent(this.send(this.kind, this.name, `${this.what} (more)`, body));
    this.update();
    return true;
  }

  /** A page from the reply topic (parsed): true when it was ours. */
  onPage(page) {
    const dropped = this.query.dropped;
    if (!this.query.take(page)) return false;
    const bad = this.query.dropped - dropped;
    if (this.query.error) this.feedback(this.name, "refused", `${this.what}: refused — ${this.query.error}`);
    else if (bad) this.feedback(this.name, "refused", `${this.what}: left out ${bad} malformed ${bad === 1 ? "entry" : "entries"} of the coordinator's`);
    else this.feedback(this.name, "", "");
    this.addRows();
    this.update();
    this.arrived();
    return true;
  }

  /** The awaited page will not come: the words are already under the form. */
  gaveUp(reason) {
    if (!this.query.busy) return;
    this.query.gaveUp(reason);
    this.update();
  }

  /** The entries not in the table yet, appended (the rows already there stay as they are). */
  addRows() {
    const rows = this.query.entries.slice(this.shown).map((e) => {
      const tr = document.createElement("tr");
      for (const [text, className] of this.cells(e, this.query.body)) {
        const td = document.createElement("td");
        td.className = className;
        td.textContent = text;
        td.title = text; // the whole of a long reason
        tr.append(td);
      }
      this.decorate(tr, e);
      return tr;
    });
    this.tbody.append(...rows);
    this.shown = this.query.entries.length;
  }

  /** A row's own classes (a subclass marks states). */
  decorate() {}

  /** After each page: a subclass goes on (a download wants every page). */
  arrived() {}

  /** The button and the table's state, for the person and for tests. */
  update() {
    this.moreButton.hidden = this.query.next == null;
    this.moreButton.disabled = this.query.busy;
    const table = this.tbody.closest("table");
    table.dataset.rows = String(this.query.entries.length);
    table.dataset.dropped = String(this.query.dropped);
    table.dataset.state = this.query.busy ? "loading" : this.query.error ? "refused" : this.query.next ? "more" : "complete";
  }
}
