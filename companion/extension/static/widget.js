// The compact view for a Cockpit iframe widget: the newest summary frames with their depth, a status light,
// "more like this" / "not this", start/stop; every URL is relative, so it works under any path prefix.
"use strict";

const TOKEN = new URLSearchParams(location.search).get("token") || "";
const SHOWN = 4;
const sentPois = new Set();
let lastKey = "";

function el(tag, cls, text) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
}

async function post(action, body) {
  const response = await fetch("api/" + action, {
    method: "POST", cache: "no-store",
    headers: { "Content-Type": "application/json", "X-Merlion-Token": TOKEN },
    body: JSON.stringify(body),
  });
  const answer = await response.json();
  if (!response.ok) throw new Error(answer.error || "refused");
  return answer;
}

// Cockpit's iframe API: a point of interest on its map for every summary frame whose position is known
function pointsOfInterest(frames) {
  const now = new Set();
  for (const f of frames) {
    if (f.lat === null || f.lon === null || f.lat === undefined || (f.lat === 0 && f.lon === 0)) continue;
    const id = "merlion-" + f.dive + "-" + f.image_index;
    now.add(id);
    if (sentPois.has(id)) continue;
    sentPois.add(id);
    const depth = f.depth_m === null ? "" : " at " + f.depth_m.toFixed(1) + " m";
    window.parent.postMessage({ type: "cockpit:addPointOfInterest", poi: {
      id: id, name: "MERLION #" + f.image_index, latitude: f.lat, longitude: f.lon, icon: "mdi-image",
      description: (f.topic || "summary") + depth + " score " + (f.score || 0).toFixed(2) } }, "*");
  }
  for (const id of Array.from(sentPois)) {
    if (!now.has(id)) {
      sentPois.delete(id);
      window.parent.postMessage({ type: "cockpit:removePointOfInterest", id: id }, "*");
    }
  }
}

function frameTile(f, marks) {
  const tile = el("div", "frame");
  tile.dataset.index = f.image_index;
  const img = el("img");
  img.alt = "#" + f.image_index;
  if (f.thumbnail) img.src = "files/" + f.thumbnail;
  tile.appendChild(img);
  const depth = f.depth_m === null || f.depth_m === undefined ? "?" : f.depth_m.toFixed(1);
  tile.appendChild(el("span", "tag", "#" + f.image_index + " " + depth + " m"));
  const row = el("div", "marks");
  const state = marks.like.includes(f.image_index) ? "like" : marks.unlike.includes(f.image_index) ? "unlike" : "none";
  for (const [kind, label] of [["like", "like"], ["unlike", "not this"]]) {
    const b = el("button", kind + (state === kind ? " on" : ""), label);
    b.type = "button";
    b.dataset.kind = kind;
    b.addEventListener("click", () => post("mark", { index: f.image_index, kind: state === kind ? "none" : kind })
      .catch((err) => { document.getElementById("status").textContent = err.message; }));
    row.appendChild(b);
  }
  tile.appendChild(row);
  return tile;
}

function render(state, extension) {
  const comp = state.companion || {};
  const age = comp.heartbeat_age_s;
  const light = document.getElementById("light");
  const warnings = (comp.warnings || []).length;
  light.className = "light " + (age === null || age === undefined ? "down" : age > 5 ? "down" : warnings ? "warn" : "ok");
  const frames = (state.summary || []).slice().sort((a, b) => b.image_index - a.image_index);
  const running = extension && extension.companion_running;
  document.getElementById("status").textContent = (age === null || age === undefined ? "no companion"
    : age > 5 ? "companion silent " + age.toFixed(0) + " s" : "companion live") + " \u00b7 "
    + frames.length + " frames";
  const run = document.getElementById("run");
  if (extension && extension.supervised) {
    run.hidden = false;
    run.textContent = running ? "stop" : "start";
    run.onclick = () => post("companion", { run: !running }).catch((err) => {
      document.getElementById("status").textContent = err.message; });
  }
  const marks = state.marks || { like: [], unlike: [] };
  const key = JSON.stringify([frames.slice(0, SHOWN), marks]);
  if (key !== lastKey) {
    lastKey = key;
    const box = document.getElementById("frames");
    box.replaceChildren(...(frames.length ? frames.slice(0, SHOWN).map((f) => frameTile(f, marks))
      : [el("p", "", "No summary frames yet.")]));
  }
  pointsOfInterest(frames);
}

async function poll() {
  try {
    const [state, extension] = await Promise.all([
      fetch("api/state", { cache: "no-store" }).then((r) => r.json()),
      fetch("api/extension", { cache: "no-store" }).then((r) => (r.ok ? r.json() : null)).catch(() => null),
    ]);
    render(state, extension);
  } catch (err) {
    document.getElementById("light").className = "light down";
    document.getElementById("status").textContent = "surface tool not answering";
  }
  setTimeout(poll, 1000);
}

poll();
