// The admin page: progress per stimulus and per participant, and the export tables.
// The admin token stays in this tab (sessionStorage) and goes in an Authorization header.
"use strict";

const tokenInput = document.getElementById("token");
tokenInput.value = sessionStorage.getItem("adminToken") || "";

function get(path, method = "GET") {
  return fetch(path, { method, headers: { Authorization: `Bearer ${tokenInput.value}` } });
}

function table(rows, columns) {
  const t = document.createElement("table");
  const head = t.insertRow();
  for (const c of columns) head.append(Object.assign(document.createElement("th"), { textContent: c }));
  for (const r of rows) {
    const tr = t.insertRow();
    for (const c of columns) tr.insertCell().textContent = r[c] === null ? "" : String(r[c]);
  }
  return t;
}

async function load() {
  const err = document.getElementById("error");
  const resp = await get("/api/admin/progress");
  if (resp.status !== 200) {
    err.textContent = "Wrong admin token.";
    return;
  }
  sessionStorage.setItem("adminToken", tokenInput.value);
  err.textContent = "";
  const p = await resp.json();
  const h = (text) => Object.assign(document.createElement("h2"), { textContent: text });
  document.getElementById("tables").replaceChildren(
    h(`${p.answers} answers; rounds ${p.rounds.join(", ")}`),
    h("Per stimulus"),
    table(p.stimuli, ["round", "id", "trajectory", "tau", "camera", "kind", "assigned", "answers"]),
    h("Per participant"),
    table(p.participants, ["participant", "external_id", "study_id", "session_id", "round",
                           "starts", "trials", "answered", "attention_answered",
                           "attention_passed", "finished"]));
  document.getElementById("export").hidden = false;
  document.getElementById("relink").hidden = false;
}

document.getElementById("login").addEventListener("submit", (e) => { e.preventDefault(); load(); });
for (const b of document.querySelectorAll("[data-table]")) {
  b.addEventListener("click", async () => {
    const resp = await get(`/api/admin/export/${b.dataset.table}.csv`);
    const url = URL.createObjectURL(await resp.blob());
    Object.assign(document.createElement("a"), { href: url, download: `${b.dataset.table}.csv` }).click();
    URL.revokeObjectURL(url);
  });
}
document.getElementById("relink").addEventListener("submit", async (e) => {
  e.preventDefault();
  const n = document.getElementById("relink-participant").value;
  const out = document.getElementById("relink-url");
  const resp = await get(`/api/admin/resume-link/${encodeURIComponent(n)}`, "POST");
  const doc = await resp.json().catch(() => ({ error: "bad response" }));
  out.value = resp.status === 200 ? doc.url : `error: ${doc.error}`;
  out.select();
});
if (tokenInput.value) load();
