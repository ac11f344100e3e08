// Table bodies updated in place: a row (and its buttons) stays the same element from one render to
// the next. Rebuilding rows on every message (units report every step) detached the "delete"
// button under the operator's pointer, so a click that straddled a render was lost.

/**
 * Make `tbody` show one row per item, in order. `key(item)` names the row (kept in
 * `tr.dataset[keyName]`); `cells(item)` gives `[text, className]` per cell; `extra(tr, item, fresh)`
 * may add to the row (e.g. a button once, when `fresh`) and set its classes. `pad` ({top, bottom}
 * in px): `items` are the rows in view of a longer table, and empty rows that high stand for the
 * rest above and below, so the box scrolls as if every row were there.
 */
export function syncRows(tbody, items, { keyName, key, cells, extra }, pad = null) {
  const old = new Map();
  for (const tr of tbody.children) if (tr.dataset[keyName] !== undefined) old.set(tr.dataset[keyName], tr);
  const rows = items.map((item) => {
    const id = key(item);
    const content = cells(item);
    let tr = old.get(id);
    const fresh = !tr;
    if (fresh) {
      tr = document.createElement("tr");
      tr.dataset[keyName] = id;
      for (const [, className] of content) {
        const td = document.createElement("td");
        if (className) td.className = className;
        tr.append(td);
      }
    }
    content.forEach(([text, className], i) => {
      const td = tr.children[i];
      if (td.textContent !== text) td.textContent = text;
      if (className && td.className !== className) td.className = className;
    });
    if (extra) extra(tr, item, fresh);
    return tr;
  });
  // Spacers only when rows are left out: a table that fits has rows and nothing else.
  if (pad?.top > 0) rows.unshift(spacer(tbody, "top", pad.top));
  if (pad?.bottom > 0) rows.push(spacer(tbody, "bottom", pad.bottom));
  // Move rows only when the order or the set changed; unchanged rows are not touched.
  const current = [...tbody.children];
  if (current.length !== rows.length || rows.some((tr, i) => current[i] !== tr)) {
    tbody.replaceChildren(...rows);
  }
}

function spacer(tbody, where, px) {
  let tr = tbody.querySelector(`:scope > tr.spacer-${where}`);
  if (!tr) {
    tr = document.createElement("tr");
    tr.className = `spacer spacer-${where}`;
    const td = document.createElement("td");
    // As many columns as the header: more would add columns to a fixed-layout table.
    td.colSpan = tbody.closest("table")?.tHead?.rows[0]?.cells.length ?? 1;
    tr.append(td);
  }
  const height = `${Math.max(0, Math.round(px))}px`;
  if (tr.firstChild.style.height !== height) tr.firstChild.style.height = height;
  return tr;
}
