// The compact view for a Cockpit iframe widget: the newest summary frames, each with its topic, score (marked when
// it was kept below the threshold), depth and capture time; a status light with the reason whenever it is not
// green; a topic switch; "more like this" / "not this"; start/stop. Every URL is relative, so it works under any
// path prefix. It posts nothing to Cockpit: Cockpit's iframe widget (src/components/widgets/IFrame.vue) answers only
// "cockpit:listenToDatalakeVariables", which this widget does not need.
"use strict";

const SHOWN = 4;
const SILENT_S = 5;
let lastKey = "";
let lastTopics = "";

function el(tag, cls, text) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
}

function known(v) { return v !== null && v !== undefined; }

function pad(n) { return String(n).padStart(2, "0"); }

function clock(t) {
  if (!known(t)) return "?";
  const d = new Date(t * 1000);
  return pad(d.getHours()) + ":" + pad(d.getMinutes()) + ":" + pad(d.getSeconds());
}

let noteUntil = 0;

// an answer to the pilot (a refusal's reason, what is followed now) stays 10 s before the live line comes back
function say(text) {
  noteUntil = Date.now() + 10000;
  const note = document.getElementById("note");
  note.textContent = text;
  note.hidden = false;
}

async function post(action, body) {
  // the JSON as text/plain, like Cockpit's actions: no CORS preflight anywhere; the vehicle checks the Origin
  const response = await fetch("api/" + action, { method: "POST", cache: "no-store", body: JSON.stringify(body) });
  const answer = await response.json().catch(() => ({ error: response.status + " " + response.statusText }));
  if (!response.ok) throw new Error(answer.error || "refused");
  return answer;
}

function frameTile(f, marks) {
  const tile = el("div", "frame" + (f.below_threshold ? " below" : ""));
  tile.dataset.index = f.image_index;
  const img = el("img");
  img.alt = "#" + f.image_index;
  if (f.thumbnail) img.src = "files/" + f.thumbnail;
  tile.appendChild(img);
  const top = el("span", "tag top");
  top.appendChild(el("span", "topic", f.topic || "no topic"));
  top.appendChild(document.createTextNode(" "));
  top.appendChild(el("span", "score", known(f.score) ? f.score.toFixed(2) : "?"));
  if (f.below_threshold) {
    top.appendChild(document.createTextNode(" "));
    top.appendChild(el("span", "below-mark", "below threshold"));
  }
  tile.appendChild(top);
  const depth = known(f.depth_m) ? f.depth_m.toFixed(1) + " m" : "? m";
  tile.appendChild(el("span", "tag bottom", "#" + f.image_index + " " + depth + " " + clock(f.time_utc)));
  const row = el("div", "marks");
  const state = marks.like.includes(f.image_index) ? "like" : marks.unlike.includes(f.image_index) ? "unlike" : "none";
  for (const [kind, label] of [["like", "like"], ["unlike", "not this"]]) {
    const b = el("button", kind + (state === kind ? " on" : ""), label);
    b.type = "button";
    b.dataset.kind = kind;
    b.addEventListener("click", () => post("mark", { index: f.image_index, kind: state === kind ? "none" : kind })
      .catch((err) => say(err.message)));
    row.appendChild(b);
  }
  tile.appendChild(row);
  return tile;
}

// green, or amber/red with the reason a pilot can act on
function light(state, extension) {
  const comp = state.companion || {};
  const age = comp.heartbeat_age_s;
  if (extension && extension.supervised && !extension.companion_running) {
    return ["down", "companion stopped (start it here or from Cockpit)"];
  }
  if (!known(age)) return ["down", "companion never heard on the link"];
  if (age > SILENT_S) return ["down", "companion silent for " + age.toFixed(0) + " s"];
  const warnings = comp.warnings || [];
  if (warnings.length) return ["warn", warnings[0].text];
  return ["ok", ""];
}

function topicSwitch(extension, state) {
  const select = document.getElementById("topic");
  const names = (extension && extension.topics) || [];
  select.hidden = names.length === 0;
  document.getElementById("ask").hidden = !extension;
  const key = JSON.stringify(names);
  if (key !== lastTopics) {
    lastTopics = key;
    select.replaceChildren(el("option", "", "topic\u2026"), ...names.map((n) => {
      const o = el("option", "", n);
      o.value = n;
      return o;
    }));
    select.firstChild.value = "";
  }
  select.title = "follow a topic (now: " + ((state.topics || []).map((t) => t.name).join(", ") || "?") + ")";
}

function render(state, extension) {
  const [level, reason] = light(state, extension);
  document.getElementById("light").className = "light " + level;
  const why = document.getElementById("reason");
  why.hidden = level === "ok";
  why.className = level;
  why.textContent = reason;
  const frames = (state.summary || []).slice().sort((a, b) => b.image_index - a.image_index);
  const following = (state.topics || []).map((t) => t.name).join(", ");
  document.getElementById("status").textContent = (level === "ok" ? "live" : level === "warn" ? "live, warning"
    : "not live") + " \u00b7 " + frames.length + " frames" + (following ? " \u00b7 " + following : "");
  document.getElementById("note").hidden = Date.now() > noteUntil;
  const run = document.getElementById("run");
  if (extension && extension.supervised) {
    const running = extension.companion_running;
    run.hidden = false;
    run.textContent = running ? "stop" : "start";
    run.onclick = () => post("companion", { run: !running }).catch((err) => say(err.message));
  }
  topicSwitch(extension, state);
  const marks = state.marks || { like: [], unlike: [] };
  const key = JSON.stringify([frames.slice(0, SHOWN), marks]);
  if (key !== lastKey) {
    lastKey = key;
    const box = document.getElementById("frames");
    box.replaceChildren(...(frames.length ? frames.slice(0, SHOWN).map((f) => frameTile(f, marks))
      : [el("p", "", "No summary frames yet.")]));
  }
}

document.getElementById("topic").addEventListener("change", (event) => {
  const name = event.target.value;
  if (!name) return;
  follow({ topic: name }, name).finally(() => { event.target.value = ""; });
});

function follow(body, what) {
  say("switching to " + what + "\u2026");
  return post("topic", body).then((answer) => say("following " + answer.topic + ": " + answer.query))
    .catch((err) => say(err.message));
}

// the pilot's own words: the companion checks them with its encoder and says why it cannot follow them
document.getElementById("ask").addEventListener("submit", (event) => {
  event.preventDefault();
  const input = document.getElementById("query");
  const words = input.value.trim();
  if (words) follow({ query: words }, "\u201c" + words + "\u201d").then(() => { input.value = ""; });
});

async function poll() {
  try {
    const [state, extension] = await Promise.all([
      fetch("api/state", { cache: "no-store" }).then((r) => r.json()),
      fetch("api/extension", { cache: "no-store" }).then((r) => (r.ok ? r.json() : null)).catch(() => null),
    ]);
    render(state, extension);
  } catch (err) {
    document.getElementById("light").className = "light down";
    const why = document.getElementById("reason");
    why.hidden = false;
    why.className = "down";
    why.textContent = "the extension's page is not answering";
    document.getElementById("status").textContent = "not live";
  }
  setTimeout(poll, 1000);
}

poll();
