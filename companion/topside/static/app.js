// Polls /api/state once a second and redraws the summary (newest first) and the status bar.
"use strict";

function fmt(value, digits, unit) {
  return value === null || value === undefined ? "?" : value.toFixed(digits) + unit;
}

function timeText(t) {
  if (t === null || t === undefined) return "?";
  const d = new Date(t * 1000);
  return d.toISOString().substring(11, 19) + " UTC";
}

function setLight(id, state, text) {
  const el = document.getElementById(id);
  el.className = state;
  el.querySelector(".text").textContent = text;
}

function ageState(age, staleAfter) {
  if (age === null || age === undefined) return "down";
  return age <= staleAfter ? "ok" : age <= 3 * staleAfter ? "stale" : "down";
}

function card(frame) {
  const fig = document.createElement("figure");
  fig.className = "frame";
  fig.dataset.index = frame.image_index;
  if (frame.thumbnail) {
    const img = document.createElement("img");
    img.src = "files/" + frame.thumbnail + "?b=" + (frame.bytes || 0);
    img.alt = "summary frame " + frame.image_index;
    fig.appendChild(img);
  } else {
    const wait = document.createElement("div");
    wait.className = "wait";
    wait.textContent = "thumbnail on its way";
    fig.appendChild(wait);
  }
  const cap = document.createElement("figcaption");
  const rows = [
    ["idx", "#" + frame.image_index + (frame.via ? " (" + frame.via + ")" : "")],
    ["dive", "dive " + (frame.dive || "?")],
    ["depth", "depth " + fmt(frame.depth_m, 1, " m")],
    ["heading", "heading " + (frame.heading_deg === null || frame.heading_deg === undefined
      ? "?" : (Math.round(frame.heading_deg) % 360) + "\u00b0")],
    ["time", timeText(frame.time_utc)],
    ["score", "score " + fmt(frame.score, 2, "")],
  ];
  for (const [cls, text] of rows) {
    const span = document.createElement("span");
    span.className = cls;
    span.textContent = text;
    cap.appendChild(span);
    cap.appendChild(document.createElement("br"));
  }
  fig.appendChild(cap);
  return fig;
}

let lastGallery = "";

function render(state) {
  const link = state.link, comp = state.companion;
  setLight("link", ageState(link.last_message_age_s, 2),
    "link: " + (link.last_message_age_s === null ? "no data" : link.messages + " msgs, last " + link.last_message_age_s + " s ago")
    + (link.lost_packets ? ", " + link.lost_packets + " lost" : ""));
  setLight("companion", ageState(comp.heartbeat_age_s, 3),
    "companion: " + (comp.id ? comp.id.join("/") + ", heartbeat " + comp.heartbeat_age_s + " s ago" : "not seen"));
  document.getElementById("dive").textContent = "dive " + (state.dive || "?");
  document.getElementById("counts").textContent =
    "push " + link.pushed_ok + " ok (" + link.verified + " CRC-checked) / " + link.pushed_lost + " lost, FTP " + link.ftp_ok + " ok / " + link.ftp_failed + " failed";
  const values = document.getElementById("values");
  values.replaceChildren(...Object.keys(comp.values).sort().map((name) => {
    const span = document.createElement("span");
    const b = document.createElement("b");
    b.textContent = name;
    span.appendChild(b);
    span.appendChild(document.createTextNode(Number(comp.values[name]).toFixed(2)));
    span.dataset.name = name;
    return span;
  }));
  const list = document.querySelector("#log ul");
  list.replaceChildren(...comp.statustext.slice(0, 15).map((line) => {
    const li = document.createElement("li");
    li.className = line.severity <= 3 ? "sev-err" : line.severity <= 5 ? "sev-warn" : "";
    li.textContent = timeText(line.time).substring(0, 8) + " " + line.text;
    return li;
  }));
  const key = JSON.stringify(state.summary);
  if (key !== lastGallery) {
    lastGallery = key;
    const gallery = document.getElementById("gallery");
    const frames = state.summary.slice().sort((a, b) => b.image_index - a.image_index);
    if (frames.length === 0) {
      gallery.innerHTML = '<p class="muted" id="empty">No summary frames yet.</p>';
    } else {
      gallery.replaceChildren(...frames.map(card));
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

poll();
