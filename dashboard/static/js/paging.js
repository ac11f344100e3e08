// A query the coordinator answers page by page (the job history §6.10, the audit §6.8): the
// entries so far, the cursor of the next page and the request still waiting for its page. Pure:
// the page sends the bodies made here (requests.js resends them until answered) and hands the
// pages that come back to `take`.

export class PagedQuery {
  /**
   * `entriesOf(page, body)`: the list a page of the query `body` carries its entries in (a page's
   * `entries` unless told); `valid(entry, body)`: whether an entry read from the wire may be kept
   * (the others are left out and counted in `dropped`, so one bad entry does not break a view).
   */
  constructor({ entriesOf = (page) => page.entries, valid = () => true } = {}) {
    this.entriesOf = entriesOf;
    this.valid = valid;
    this.body = null; // the query, cursor left out
    this.entries = [];
    this.dropped = 0; // entries of this query's pages left out as malformed
    this.next = null; // the next page's cursor; null: no more
    this.waiting = null; // the request id whose page has not come yet
    this.error = null; // why the coordinator refused it, in its words
    this.generation = 0; // a new query: the pages of an earlier one are not ours any more
  }

  /** A new query: what was loaded goes; returns the first page's request body. */
  begin(body) {
    this.body = { ...body, cursor: null };
    this.entries = [];
    this.dropped = 0;
    this.next = null;
    this.waiting = null;
    this.error = null;
    this.generation += 1;
    return this.body;
  }

  /** The next page's request body, or null when the last page is in (or one is on its way). */
  more(limit = this.body?.limit) {
    if (!this.body || this.next == null || this.waiting) return null;
    return { ...this.body, limit, cursor: this.next };
  }

  /** The request `id` carries this query's next page. */
  sent(id) {
    this.waiting = id;
  }

  /** True while a page is awaited. */
  get busy() { return this.waiting != null; }

  /** True when every page is in. */
  get complete() { return !!this.body && !this.waiting && this.next == null && !this.error; }

  /**
   * A page (parsed JSON) from the reply topic. True when it was this query's awaited page, now
   * taken: its entries appended, or its refusal kept in `error`; false for anybody else's.
   */
  take(page) {
    if (!page || page.request_id == null || page.request_id !== this.waiting) return false;
    this.waiting = null;
    if (!page.accepted) {
      this.error = page.reason ?? "refused, no reason given";
      this.next = null;
      return true;
    }
    const got = this.entriesOf(page, this.body);
    for (const e of Array.isArray(got) ? got : []) {
      if (this.valid(e, this.body)) this.entries.push(e);
      else this.dropped += 1;
    }
    this.next = page.next_cursor ?? null;
    return true;
  }

  /** The awaited page will not come (no answer, or a refusal on the plain reply topic). */
  gaveUp(reason) {
    this.waiting = null;
    this.error = reason;
  }
}
