// Sort and filter the ranked table, offline. Without script the table stays ranked as written.
(function () {
  "use strict";
  var table = document.getElementById("ranked-table");
  if (!table) return;
  var body = table.tBodies[0], rows = Array.prototype.slice.call(body.rows);
  var q = document.getElementById("q"), fv = document.getElementById("fv"),
      fn = document.getElementById("fn"), shown = document.getElementById("shown");
  document.getElementById("controls").hidden = false;
  function key(row, i, numeric) {
    var c = row.cells[i], v = c.getAttribute("data-v");
    if (v === null) v = c.textContent.trim();
    if (!numeric) return v.toLowerCase();
    return v === "" ? null : parseFloat(v);
  }
  Array.prototype.forEach.call(table.tHead.rows[0].cells, function (th, i) {
    var t = th.getAttribute("data-t");
    if (!t) return;
    th.tabIndex = 0;
    function sort() {
      var asc = th.getAttribute("aria-sort") !== "ascending";
      Array.prototype.forEach.call(th.parentNode.cells, function (o) { o.removeAttribute("aria-sort"); });
      th.setAttribute("aria-sort", asc ? "ascending" : "descending");
      var keyed = rows.map(function (r, k) { return [key(r, i, t === "n"), k, r]; });
      keyed.sort(function (a, b) {
        if (a[0] === b[0]) return a[1] - b[1];
        if (a[0] === null || a[0] === "") return 1;   // empty cells last, either way
        if (b[0] === null || b[0] === "") return -1;
        return (a[0] < b[0] ? -1 : 1) * (asc ? 1 : -1);
      });
      keyed.forEach(function (x) { body.appendChild(x[2]); });
    }
    th.addEventListener("click", sort);
    th.addEventListener("keydown", function (e) { if (e.key === "Enter") sort(); });
  });
  function filter() {
    var text = q.value.trim().toLowerCase(), v = fv.value, onlyNew = fn.checked, n = 0;
    rows.forEach(function (r) {
      var verdict = r.getAttribute("data-verdict");
      var ok = (!text || r.cells[1].textContent.toLowerCase().indexOf(text) >= 0 ||
                r.cells[2].textContent.toLowerCase().indexOf(text) >= 0) &&
               (!v || v === verdict || (v === "action" && r.cells[0].textContent.trim() !== "")) &&
               (!onlyNew || r.getAttribute("data-status") === "new");
      r.hidden = !ok;
      if (ok) n++;
    });
    shown.textContent = n + " of " + rows.length + " loops shown";
  }
  q.addEventListener("input", filter); fv.addEventListener("change", filter);
  fn.addEventListener("change", filter);
  filter();
})();
