// The tabs beside the map: the fleet now (the forms, tables, events and charts) or one of the
// records (History, Audit, Alerts). The map stays in view whichever is chosen.

const PANELS = { fleet: "#fleet-panel", history: "#history-panel", audit: "#audit-panel", alerts: "#alerts-panel" };

export class Tabs {
  /** `onOpen(name)` hears a tab chosen (a view fetches what it shows when first opened). */
  constructor({ onOpen }) {
    this.onOpen = onOpen;
    this.current = "fleet";
    this.buttons = [...document.querySelectorAll("#tabs [data-tab]")];
    for (const b of this.buttons) b.addEventListener("click", () => this.show(b.dataset.tab));
  }

  /** Show tab `name` (hidden panels keep what they hold). */
  show(name) {
    if (!PANELS[name] || this.current === name) return;
    this.current = name;
    for (const b of this.buttons) b.setAttribute("aria-selected", String(b.dataset.tab === name));
    document.querySelector("#side").dataset.tab = name;
    for (const [tab, sel] of Object.entries(PANELS)) {
      if (tab !== "fleet") document.querySelector(sel).hidden = tab !== name;
    }
    this.onOpen(name);
  }

  /** Offer tab `name` or not (the Audit for accounts that may read it). */
  offer(name, shown) {
    const b = this.buttons.find((x) => x.dataset.tab === name);
    if (b) b.hidden = !shown;
  }
}
