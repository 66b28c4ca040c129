// The surface page. Served by `merlion surface --web`, it polls api/state once a second; opened from disk
// (DIR/index.html, no server), it draws the state.js written beside it once. Same drawing either way.
"use strict";

const LIVE = location.protocol !== "file:";
const FILES = LIVE ? "files/" : "";
// the per-run token from the URL the tool printed: a full-frame fetch spends link bandwidth, so it must carry it
const TOKEN = new URLSearchParams(location.search).get("token") || "";

// the companion's NAMED_VALUE_FLOAT names, as a pilot reads them: label, decimals, unit
const VALUE_LABELS = {
  MRL_FPS: ["Frames", 1, "/s"],
  MRL_SEEN: ["Seen", 1, "/s"],
  MRL_SCORE: ["Latest frame", 2, ""],
  MRL_SUMN: ["Summary", 0, "frames"],
  MRL_LINKBS: ["Link", 0, "B/s"],
  MRL_DEPTH: ["Depth", 1, "m"],
};

function known(value) {
  return value !== null && value !== undefined && !Number.isNaN(value);
}

function fmt(value, digits, unit) {
  return known(value) ? value.toFixed(digits) + unit : "?";
}

function pad(n) {
  return String(n).padStart(2, "0");
}

// local time beside UTC: the pilot's clock and the log's
function timeText(t) {
  if (!known(t)) return "?";
  const d = new Date(t * 1000);
  return pad(d.getHours()) + ":" + pad(d.getMinutes()) + ":" + pad(d.getSeconds()) + " local ("
    + d.toISOString().substring(11, 19) + " UTC)";
}

function shortTime(t) {
  const d = new Date(t * 1000);
  return pad(d.getHours()) + ":" + pad(d.getMinutes()) + ":" + pad(d.getSeconds());
}

function positionText(frame) {
  if (!known(frame.lat) || !known(frame.lon)) return null;
  const ns = frame.lat >= 0 ? "N" : "S", ew = frame.lon >= 0 ? "E" : "W";
  return Math.abs(frame.lat).toFixed(5) + "\u00b0" + ns + " " + Math.abs(frame.lon).toFixed(5) + "\u00b0" + ew;
}

function valueText(name, value, values) {
  // frames scored, not the camera's rate: said beside what the camera delivers (MRL_SEEN)
  if (name === "MRL_FPS") {
    const seen = values ? values.MRL_SEEN : undefined;
    return ["Frames", "scored " + fmt(value, 1, "/s") + (known(seen) ? " of " + fmt(seen, 1, "/s") + " seen" : "")];
  }
  // the frame just scored, not the summary's: said so beside the cards' scores (a 0.06 beside cards at 1.00)
  if (name === "MRL_SCORE") return ["Latest frame", "score " + fmt(value, 2, "")];
  const label = VALUE_LABELS[name];
  if (!label) return [name, known(value) ? Number(value).toFixed(2) : "?"];
  return [label[0], known(value) ? Number(value).toFixed(label[1]) + (label[2] ? " " + label[2] : "") : "?"];
}

function setLight(id, state, text) {
  const el = document.getElementById(id);
  el.className = state;
  el.querySelector(".text").textContent = text;
}

function ageState(age, staleAfter) {
  if (!known(age)) return "down";
  return age <= staleAfter ? "ok" : age <= 3 * staleAfter ? "stale" : "down";
}

function el(tag, className, text) {
  const node = document.createElement(tag);
  if (className) node.className = className;
  if (text !== undefined) node.textContent = text;
  return node;
}

// --- the full frame, fetched from the vehicle over MAVLink FTP when asked for --------------------------------

function openViewer(frame) {
  const viewer = document.getElementById("viewer");
  const img = viewer.querySelector("img");
  const note = viewer.querySelector(".note");
  viewer.hidden = false;
  img.removeAttribute("src");
  if (!LIVE) {  // no vehicle to ask from a file on disk: the thumbnail, as large as it goes
    img.src = FILES + frame.thumbnail;
    note.textContent = "#" + frame.image_index + " thumbnail (the full frame is on the vehicle)";
    return;
  }
  note.textContent = "#" + frame.image_index + ": fetching the full frame from the vehicle (MAVLink FTP)\u2026";
  img.onload = () => { note.textContent = "#" + frame.image_index + " full frame, " + img.naturalWidth + "\u00d7"
    + img.naturalHeight + ", depth " + fmt(frame.depth_m, 1, " m") + ", " + timeText(frame.time_utc); };
  img.onerror = () => { note.textContent = "#" + frame.image_index + ": the vehicle did not send the full frame"
    + " (trimmed meanwhile, or the link is too slow)"; };
  img.src = "full/" + frame.image_index + ".jpg?dive=" + encodeURIComponent(frame.dive || "")
    + "&token=" + encodeURIComponent(TOKEN);
}

function closeViewer() {
  document.getElementById("viewer").hidden = true;
}

// --- cards ---------------------------------------------------------------------------------------------------

// "more like this" / "not this": POST api/mark with the run's token; the tool sends the marks to the companion
async function sendMark(index, kind, status) {
  status.textContent = "sending\u2026";
  try {
    const response = await fetch("api/mark", {
      method: "POST", cache: "no-store",
      headers: { "Content-Type": "application/json", "X-Merlion-Token": TOKEN },
      body: JSON.stringify({ index: index, kind: kind }),
    });
    const answer = await response.json();
    status.textContent = response.ok ? "" : (answer.error || "refused");
  } catch (err) {
    status.textContent = "surface tool not answering";
  }
}

function markButtons(frame, marks) {
  const row = el("div", "marks");
  const state = marks.like.includes(frame.image_index) ? "like"
    : marks.unlike.includes(frame.image_index) ? "unlike" : "none";
  const status = el("span", "mark-status");
  for (const [kind, label, title] of [["like", "more like this", "keep frames like this one"],
                                      ["unlike", "not this", "keep fewer frames like this one"]]) {
    const button = el("button", "mark " + kind + (state === kind ? " on" : ""), label);
    button.type = "button";
    button.title = state === kind ? "marked: click to unmark" : title;
    button.dataset.kind = kind;
    button.addEventListener("click", () => sendMark(frame.image_index, state === kind ? "none" : kind, status));
    row.appendChild(button);
  }
  row.appendChild(status);
  return row;
}

function card(frame, marks, showTopic) {
  const fig = el("figure", "frame");
  fig.dataset.index = frame.image_index;
  if (frame.thumbnail) {
    const img = el("img");
    img.src = FILES + frame.thumbnail + "?b=" + (frame.bytes || 0);
    img.alt = "summary frame " + frame.image_index;
    img.title = "click for the full frame";
    img.addEventListener("click", () => openViewer(frame));
    fig.appendChild(img);
  } else {
    fig.appendChild(el("div", "wait", "thumbnail on its way"));
  }
  const cap = el("figcaption");
  const rows = [
    ["idx", "#" + frame.image_index + (frame.via ? " (" + frame.via + ")" : "")],
    ["dive", "dive " + (frame.dive || "?")],
    ["depth", "depth " + fmt(frame.depth_m, 1, " m")],
    ["heading", "heading " + (known(frame.heading_deg) ? (Math.round(frame.heading_deg) % 360) + "\u00b0" : "?")],
    ["time", timeText(frame.time_utc)],
    ["score", "score " + fmt(frame.score, 2, "") + (known(frame.raw_score) ? " (raw " + fmt(frame.raw_score, 2, "") + ")" : "")
      + (frame.below_threshold ? " (below threshold)" : "")],
  ];
  if (showTopic) rows.splice(1, 0, ["topic", "topic " + (frame.topic || "?")]);
  const where = positionText(frame);
  if (where) rows.splice(4, 0, ["position", where]);
  for (const [cls, text] of rows) {
    cap.appendChild(el("span", cls, text));
    cap.appendChild(el("br"));
  }
  fig.appendChild(cap);
  if (LIVE && marks) fig.appendChild(markButtons(frame, marks));
  return fig;
}

// --- depth over time, the summary frames marked on it -------------------------------------------------------

const SVG = "http://www.w3.org/2000/svg";

function svg(tag, attrs) {
  const node = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  return node;
}

function drawDepth(track, frames) {
  const plot = document.getElementById("depth-plot");
  const marks = frames.filter((f) => known(f.time_utc) && known(f.depth_m));
  const points = track.filter((p) => known(p[1]));
  plot.replaceChildren();
  const W = 800, H = 160, L = 46, R = 10, T = 10, B = 24;
  plot.setAttribute("viewBox", "0 0 " + W + " " + H);
  if (points.length + marks.length === 0) {
    plot.appendChild(Object.assign(svg("text", { x: L, y: H / 2, class: "axis" }), { textContent: "no depth yet" }));
    return;
  }
  const times = points.map((p) => p[0]).concat(marks.map((f) => f.time_utc));
  const depths = points.map((p) => p[1]).concat(marks.map((f) => f.depth_m));
  let t0 = Math.min(...times), t1 = Math.max(...times);
  if (t1 - t0 < 10) t1 = t0 + 10;
  const d0 = Math.min(0, ...depths), d1 = Math.max(1, ...depths) * 1.05;
  const x = (t) => L + (W - L - R) * (t - t0) / (t1 - t0);
  const y = (d) => T + (H - T - B) * (d - d0) / (d1 - d0);  // deeper is lower, as a pilot pictures it
  for (const frac of [0, 0.5, 1]) {
    const d = d0 + (d1 - d0) * frac;
    plot.appendChild(svg("line", { x1: L, x2: W - R, y1: y(d), y2: y(d), class: "grid" }));
    plot.appendChild(Object.assign(svg("text", { x: L - 4, y: y(d) + 4, class: "axis", "text-anchor": "end" }),
      { textContent: d.toFixed(0) + " m" }));
  }
  for (const t of [t0, (t0 + t1) / 2, t1]) {
    plot.appendChild(Object.assign(svg("text", { x: x(t), y: H - 6, class: "axis", "text-anchor": "middle" }),
      { textContent: shortTime(t) }));
  }
  const line = points.length ? points : marks.slice().sort((a, b) => a.time_utc - b.time_utc)
    .map((f) => [f.time_utc, f.depth_m]);
  plot.appendChild(svg("polyline", {
    class: "track", points: line.map((p) => x(p[0]).toFixed(1) + "," + y(p[1]).toFixed(1)).join(" "),
  }));
  for (const f of marks) {
    const dot = svg("circle", { cx: x(f.time_utc), cy: y(f.depth_m), r: 5, class: "mark" });
    dot.dataset.index = f.image_index;
    const title = svg("title", {});
    title.textContent = "#" + f.image_index + " at " + f.depth_m.toFixed(1) + " m, " + timeText(f.time_utc)
      + ", score " + fmt(f.score, 2, "");
    dot.appendChild(title);
    if (f.thumbnail) dot.addEventListener("click", () => openViewer(f));
    plot.appendChild(dot);
  }
}

// --- status lines: warnings apart from the summary's own news -----------------------------------------------

const SUMMARY_LINE = /^Summary [+-]#\d+/;

function lines(id, items, limit) {
  const list = document.querySelector("#" + id + " ul");
  list.replaceChildren(...items.slice(0, limit).map((line) => {
    const li = el("li", line.severity <= 3 ? "sev-err" : line.severity <= 5 ? "sev-warn" : "");
    li.appendChild(el("span", "when", shortTime(line.time)));
    li.appendChild(document.createTextNode(" " + line.text));
    return li;
  }));
  document.getElementById(id).classList.toggle("empty", items.length === 0);
}

// --- topics: a section per topic when the companion follows several, headed by the topic's positive query ---

// null when one topic (or none) is followed: the gallery then looks as it always did
function topicGroups(topics, frames) {
  // the companion's order; topics its index.json has not listed yet (named by a status line) after, by name
  const names = topics.map((t) => t.name);
  const more = [...new Set(frames.map((f) => f.topic).filter((n) => n && !names.includes(n)))].sort();
  names.push(...more);
  if (names.length <= 1) return null;
  const byName = Object.fromEntries(topics.map((t) => [t.name, t]));
  const groups = names.map((name) => ({
    name: name, query: byName[name] ? byName[name].positive : "", frames: frames.filter((f) => f.topic === name),
  }));
  const unknown = frames.filter((f) => !f.topic || !names.includes(f.topic));
  if (unknown.length) groups.push({ name: "", query: "", frames: unknown });  // its index.json is on its way
  return groups;
}

function topicSection(group, marks) {
  const section = el("section", "topic");
  section.dataset.topic = group.name;
  const heading = el("h2");
  heading.appendChild(el("span", "query", group.query || (group.name ? group.name : "topic not known yet")));
  const count = group.frames.length + (group.frames.length === 1 ? " frame" : " frames");
  heading.appendChild(el("span", "muted", " " + (group.name ? "topic " + group.name + ", " : "") + count));
  section.appendChild(heading);
  const cards = el("div", "cards");
  if (group.frames.length === 0) cards.appendChild(el("p", "muted", "No summary frames yet."));
  for (const frame of group.frames) cards.appendChild(card(frame, marks, true));
  section.appendChild(cards);
  return section;
}

let lastGallery = "";

function render(state) {
  const link = state.link, comp = state.companion;
  document.getElementById("dive").textContent = "dive " + (state.dive || "?");
  document.getElementById("clock").textContent = timeText(state.time) + (LIVE ? "" : " \u2014 saved page");
  // a saved page shows what was, not what is: its lights are grey ("saved"), never a green "live"
  const light = (age, staleAfter) => (LIVE ? ageState(age, staleAfter) : "saved");
  const when = LIVE ? "" : " (when saved)";
  setLight("link", light(link.last_message_age_s, 2),
    "link: " + (!known(link.last_message_age_s) ? "no data" : link.messages + " msgs, last "
      + link.last_message_age_s + " s ago") + (link.lost_packets ? ", " + link.lost_packets + " lost" : "") + when);
  setLight("companion", light(comp.heartbeat_age_s, 3),
    "companion: " + (comp.id ? comp.id.join("/") + ", heartbeat " + comp.heartbeat_age_s + " s ago" : "not seen")
      + when);
  document.getElementById("counts").textContent =
    "thumbnails: push " + link.pushed_ok + " ok (" + link.verified + " CRC-checked) / " + link.pushed_lost
    + " lost, FTP " + link.ftp_ok + " ok / " + link.ftp_failed + " failed";
  const values = document.getElementById("values");
  const shown = Object.keys(comp.values).sort().filter((name) => name !== "MRL_SEEN" || !("MRL_FPS" in comp.values));
  values.replaceChildren(...shown.map((name) => {
    const [label, text] = valueText(name, comp.values[name], comp.values);
    const span = el("span");
    span.appendChild(el("b", "", label));
    span.appendChild(document.createTextNode(" " + text));
    span.dataset.name = name;
    span.title = name;
    return span;
  }));
  const all = comp.statustext || [];
  lines("warnings", comp.warnings || all.filter((l) => l.severity <= 4), 10);
  lines("events", all.filter((l) => SUMMARY_LINE.test(l.text)), 12);
  lines("status", all.filter((l) => !SUMMARY_LINE.test(l.text) && l.severity > 4), 8);
  const frames = state.summary.slice().sort((a, b) => b.image_index - a.image_index);
  drawDepth(comp.depth_track || [], frames);
  const marks = state.marks || { like: [], unlike: [] };
  const topics = state.topics || [];
  const key = JSON.stringify([state.summary, marks, topics]);
  if (key !== lastGallery) {
    lastGallery = key;
    const gallery = document.getElementById("gallery");
    const groups = topicGroups(topics, frames);
    gallery.classList.toggle("grouped", groups !== null);
    if (groups !== null) {
      gallery.replaceChildren(...groups.map((group) => topicSection(group, marks)));
    } else if (frames.length === 0) {
      gallery.replaceChildren(el("p", "muted", "No summary frames yet."));
    } else {
      gallery.replaceChildren(...frames.map((frame) => card(frame, marks, false)));
    }
  }
}

async function poll() {
  try {
    const response = await fetch("api/state", { cache: "no-store" });
    if (response.ok) render(await response.json());
  } catch (err) {
    setLight("link", "down", "link: surface tool not answering");
  }
  setTimeout(poll, 1000);
}

// --- the topic switch, where the page's host has one (the BlueOS extension answers api/extension) ------------

let followShown = "";

async function followSwitch() {
  let extension = null;
  try {
    const response = await fetch("api/extension", { cache: "no-store" });
    if (response.ok) extension = await response.json();
  } catch (err) {
    extension = null;
  }
  const form = document.getElementById("follow");
  form.hidden = !extension;
  const names = (extension && extension.topics) || [];
  if (JSON.stringify(names) !== followShown) {
    followShown = JSON.stringify(names);
    const select = document.getElementById("follow-topic");
    select.replaceChildren(...names.map((n) => { const o = el("option", "", n); o.value = n; return o; }));
    select.hidden = names.length === 0;
  }
  if (extension) setTimeout(followSwitch, 5000);
}

document.getElementById("follow").addEventListener("submit", async (event) => {
  event.preventDefault();
  const words = document.getElementById("follow-query").value.trim();
  const body = words ? { query: words } : { topic: document.getElementById("follow-topic").value };
  const note = document.getElementById("follow-note");
  note.textContent = "switching\u2026";
  try {
    const response = await fetch("api/topic", { method: "POST", cache: "no-store", body: JSON.stringify(body) });
    const answer = await response.json();
    if (!response.ok) throw new Error(answer.error || "refused");
    note.textContent = "following " + answer.topic + ": " + answer.query;
    document.getElementById("follow-query").value = "";
  } catch (err) {
    note.textContent = err.message;
  }
});

document.getElementById("viewer").addEventListener("click", closeViewer);
document.addEventListener("keydown", (e) => { if (e.key === "Escape") closeViewer(); });
if (!LIVE) document.querySelectorAll("a[data-file]").forEach((a) => { a.href = a.dataset.file; });
if (window.MERLION_STATE) render(window.MERLION_STATE);
if (LIVE) poll();
if (LIVE) followSwitch();
