// The participant page of a slotv_jax legibility study.
// A timeline of trials (as in jsPsych): the server says what comes next (GET /api/state),
// the page shows it, and every answer is sent the moment it is given (POST /api/answer).
// A refresh, the back button or a lost connection asks the server again and lands on the
// same unanswered trial; a failed submission is retried with the same body (stored once).
// A start whose reply was lost is sent again and resumes the same participant (the server
// allows that until their first answer; then it says to ask the researcher, whose resume
// link, /#resume=<token>, opens the study where the participant was, in any browser).
"use strict";

const app = document.getElementById("app");
const banner = document.getElementById("banner");
const ID_NAMES = ["PROLIFIC_PID", "STUDY_ID", "SESSION_ID", "workerId", "hitId",
                  "assignmentId", "participant", "study", "session"];

function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "onclick") e.addEventListener("click", v);
    else if (k === "text") e.textContent = v;
    else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c);
  return e;
}

function show(...children) {
  app.replaceChildren(...children);
  window.scrollTo(0, 0);
}

function sleep(ms) { return new Promise((r) => setTimeout(r, ms)); }

// fetch with retries on network errors and 5xx (a lost connection); JSON both ways.
async function api(path, body) {
  const opts = body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  };
  opts.credentials = "same-origin";
  for (let attempt = 0; ; attempt++) {
    let resp;
    try {
      resp = await fetch(path, opts);
    } catch (err) {
      resp = null;
    }
    if (resp && resp.status < 500) {
      banner.hidden = true;
      const doc = await resp.json().catch(() => ({ error: "bad response" }));
      return { status: resp.status, doc };
    }
    banner.textContent = "Connection lost, trying again…";
    banner.hidden = false;
    await sleep(Math.min(500 * 2 ** attempt, 8000));
  }
}

function urlIds() {
  const p = new URLSearchParams(window.location.search);
  const ids = {};
  for (const n of ID_NAMES) if (p.get(n)) ids[n] = p.get(n);
  return ids;
}

function textPage(html, label, next) {
  const box = el("div", { class: "text" });
  box.innerHTML = html; // the researcher's own consent / instructions file
  const btn = el("button", { class: "primary", id: "next", onclick: next, text: label });
  show(box, el("p", {}, btn));
}

async function welcome() {
  const { doc: texts } = await api("/api/texts");
  document.title = texts.title;
  textPage(texts.consent, "I agree to take part", () => {
    textPage(texts.instructions, "Start", async () => {
      document.getElementById("next").disabled = true;
      const { status, doc } = await api("/api/start", { consent: true, ids: urlIds() });
      if (status !== 200) return message(doc.error || "The study could not start.");
      render(doc);
    });
  });
}

function message(text) {
  show(el("div", { class: "text" }, el("p", { id: "message", text })));
}

function done(state) {
  const parts = [el("h1", { text: "Thank you!" }),
    el("p", { text: "You have finished the study. Your completion code is:" }),
    el("p", {}, el("span", { class: "code", id: "code", text: state.code }))];
  if (state.url) {
    const a = el("a", { href: state.url, id: "complete", text: "Return to the study platform" });
    parts.push(el("p", {}, a));
  }
  show(el("div", { class: "text" }, ...parts));
}

function trial(state) {
  history.pushState({ position: state.position }, "");
  const title = state.practice ? "Practice trial" : `Video ${state.number} of ${state.count}`;
  const header = el("div", { class: "header" }, el("h1", { text: title }),
    el("span", { class: "progress", text: state.practice ? "(not counted)" : "" }));
  const stage = el("div", { class: "stage" });
  const video = el("video", { id: "clip", muted: "", playsinline: "", autoplay: "",
                              disablepictureinpicture: "", preload: "auto" });
  video.muted = true;
  video.src = state.clip;
  stage.append(video);
  const question = el("p", { class: "question", text: "The video plays once. Watch the robot." });
  const answer = el("div", { id: "answer", hidden: "" });
  show(header, stage, question, answer);

  let shownAt = 0, chosen = null, chosenAt = 0, sent = false;
  const choose = (g) => {
    chosen = g;
    chosenAt = performance.now();
    for (const b of document.querySelectorAll("[data-goal]"))
      b.classList.toggle("selected", b.dataset.goal === g);
    submit.disabled = false;
  };
  const submit = el("button", { class: "primary", id: "submit", text: "Next" });
  submit.disabled = true;
  const conf = el("div", { class: "confidence" });
  if (state.confidence) {
    conf.append(el("span", { text: "How sure are you? (optional) " }));
    const labels = ["1 (guess)", "2", "3", "4", "5 (sure)"];
    labels.forEach((l, i) => {
      const r = el("input", { type: "radio", name: "confidence", value: String(i + 1),
                              id: `conf${i + 1}` });
      conf.append(el("label", {}, r, " " + l));
    });
  }
  submit.addEventListener("click", async () => {
    if (sent || chosen === null) return;
    sent = true;
    submit.disabled = true;
    const c = document.querySelector("input[name=confidence]:checked");
    const body = { position: state.position, guess: chosen,
                   confidence: c ? Number(c.value) : null,
                   response_ms: Math.round(chosenAt - shownAt) };
    const { status, doc } = await api("/api/answer", body);
    if (status === 401) return welcome(); // this browser's token was replaced: start again
    if (status !== 200) return message(doc.error || "The answer could not be stored.");
    render(doc.state);
  });

  const reveal = () => {
    if (shownAt) return;
    shownAt = performance.now();
    const img = el("img", { id: "still", src: state.still, alt: "The robot where it stopped" });
    stage.replaceChildren(img);
    state.goal_pixels.forEach(([x, y], k) => {
      const g = state.goals[k];
      const b = el("button", { class: "hotspot", "data-goal": g, "aria-label": `object ${g}`,
                               onclick: () => choose(g), text: g });
      b.style.left = `${100 * x}%`;
      b.style.top = `${100 * y}%`;
      stage.append(b);
    });
    question.textContent = "Which object is the robot reaching for?";
    const row = el("div", { class: "choices" });
    for (const g of state.goals)
      row.append(el("button", { "data-goal": g, onclick: () => choose(g), text: g }));
    answer.replaceChildren(row, conf, el("p", {}, submit));
    answer.hidden = false;
  };
  video.addEventListener("ended", reveal);
  video.addEventListener("error", () => {
    question.textContent = "The video could not be loaded; reload the page to try again.";
  });
  video.play().catch(() => {
    const play = el("button", { class: "primary", id: "play", text: "Play the video",
                                onclick: () => { play.remove(); video.play(); } });
    question.replaceChildren(play);
  });
}

function render(state) {
  if (state.stage === "done") return done(state);
  return trial(state);
}

// A resume link from the researcher: take its token (the server sets the cookie), then
// drop it from the address bar so that it is not bookmarked or shared by mistake.
async function resume(token) {
  history.replaceState(null, "", window.location.pathname + window.location.search);
  const { status, doc } = await api("/api/resume", { token });
  if (status !== 200) {
    return message("This link to continue the study does not work (it was replaced by a " +
                   "newer one, or mistyped). Please ask the researcher for a new link.");
  }
  render(doc);
}

async function main() {
  const link = window.location.hash.match(/^#resume=([A-Za-z0-9_-]{1,100})$/);
  if (link) return resume(link[1]);
  const { status, doc } = await api("/api/state");
  if (status === 401) return welcome();
  if (status !== 200) return message(doc.error || "Something went wrong.");
  render(doc);
}

// The back button never leaves a trial: ask the server where the participant is.
window.addEventListener("popstate", () => main());
main();
