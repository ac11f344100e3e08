// The Audit tab (operator accounts only): who did what and when, page by page (protocol.md §6.8).

import { AUDIT_PAGE, auditCells, auditQuery } from "./audit.js";
import { stampText } from "./history.js";
import { PagedView } from "./paged_view.js";

export class AuditView extends PagedView {
  /** `send` and `feedback` as PagedView's. */
  constructor({ send, feedback }) {
    super({
      name: "audit", kind: "audit", what: "audit",
      makeQuery: (fields, now, limit = AUDIT_PAGE) => auditQuery(fields, now, limit),
      cells: (e) => auditCells(e, stampText),
      send, feedback,
    });
  }

  decorate(tr, e) {
    tr.dataset.act = e.act ?? "";
  }
}
