// The review page of a photo batch (/review/<job id>): each photo the engine left for a person, its four turns side
// by side, one click or key to pick the upright one or to leave it. Data: GET /v1/photos/batches/<id>/review;
// thumbnails: GET /v1/photos/batches/<id>/photos/<index>/thumbnail (made when asked), fetched only when a photo
// scrolls into view;
// a decision: POST /v1/photos/batches/<id>/review/<index> {rotation_degrees, reviewer}.
// The API helper is the viewer's (app/static/api.js, served under /viewer/).
import { api, rememberKey, startingKey } from "/viewer/api.js";

const $ = (id) => document.getElementById(id);
const TURNS = [0, 90, 180, 270];
const LEAVE = 4; // the option after the four turns
const state = {
  job: decodeURIComponent(location.pathname.replace(/\/+$/, "").split("/").pop()),
  key: startingKey(),
  items: [], current: 0, selected: new Map(), pending: false, loaded: 0, errors: [],
};
window.reviewState = state; // read by the browser tests and handy in the console

function say(text, isError = false) {
  $("status").textContent = text;
  $("status").classList.toggle("error", isError);
  if (isError) state.errors.push(text);
}

// --- the queue ---------------------------------------------------------------------------------
async function load() {
  let queue;
  try {
    queue = await (await api(`/v1/photos/batches/${encodeURIComponent(state.job)}/review`, state.key)).json();
  } catch (error) {
    say(error.status === 401 ? "this service needs an API key: enter it above" : error.message, true);
    return;
  }
  state.items = queue.items;
  render(queue);
  const first = state.items.findIndex((item) => !item.review);
  focusItem(first >= 0 ? first : 0);
  say(state.items.length ? "" : "nothing to review in this batch");
}

function describe(item) {
  const why = { no_cue: "no face and no readable text", conflicting_rotations: "cues point different ways",
                low_confidence: "a cue, not clear enough", conflicting_metadata: "the file's orientations disagree" };
  return `${why[item.reason] || item.reason || ""}: ${item.message}`;
}

function render(queue) {
  const main = $("queue");
  main.replaceChildren();
  state.items.forEach((item, i) => {
    const section = document.createElement("section");
    section.className = "item";
    section.setAttribute("role", "listitem");
    section.dataset.index = String(item.index);
    const title = document.createElement("h2");
    title.textContent = `${item.index + 1}. ${item.filename}`;
    const why = document.createElement("p");
    why.className = "why";
    why.textContent = describe(item);
    const options = document.createElement("div");
    options.className = "options";
    TURNS.forEach((turn, k) => options.append(option(i, k, `${turn}\u00b0`, turn)));
    options.append(option(i, LEAVE, "leave it", null));
    const decided = document.createElement("p");
    decided.className = "decided";
    section.append(title, why, options, decided);
    section.addEventListener("click", () => focusItem(i));
    main.append(section);
    showDecision(i);
    observer.observe(section);
  });
  updateProgress();
}

function option(i, k, label, turn) {
  const button = document.createElement("button");
  button.type = "button";
  button.className = turn === null ? "option leave" : "option";
  button.dataset.option = String(k);
  button.title = turn === null ? "leave it as it is (0)" : `upright when turned ${turn}\u00b0 clockwise (${k + 1})`;
  if (turn !== null) {
    const frame = document.createElement("span");
    frame.className = "frame";
    const img = document.createElement("img");
    img.alt = `turned ${turn} degrees`;
    img.style.transform = `rotate(${turn}deg)`;
    frame.append(img);
    button.append(frame);
  }
  const caption = document.createElement("span");
  caption.textContent = label;
  button.append(caption);
  button.addEventListener("click", (event) => {
    event.stopPropagation();
    focusItem(i);
    select(k);
    decide();
  });
  return button;
}

// Thumbnails load only for the photos in or near view: a 500-photo batch never fetches them all at once.
const observer = new IntersectionObserver((entries) => {
  for (const entry of entries) {
    if (!entry.isIntersecting) continue;
    observer.unobserve(entry.target);
    const item = state.items.find((it) => String(it.index) === entry.target.dataset.index);
    if (item && item.thumbnail) loadThumbnail(item, entry.target);
  }
}, { rootMargin: "600px 0px" });

async function loadThumbnail(item, section) {
  try {
    const response = await api(item.thumbnail, state.key);
    const url = URL.createObjectURL(await response.blob());
    const images = Array.from(section.querySelectorAll("img"));
    images.forEach((img) => { img.src = url; });
    await Promise.all(images.map((img) => img.decode()));  // counted once it can be drawn, not when asked for
    state.loaded += 1;
  } catch (error) {
    say(`thumbnail of ${item.filename}: ${error.message}`, true);
  }
}

// --- choosing ----------------------------------------------------------------------------------
function sections() { return $("queue").children; }

function focusItem(i) {
  if (!state.items.length) return;
  state.current = Math.max(0, Math.min(state.items.length - 1, i));
  Array.from(sections()).forEach((s, k) => s.classList.toggle("current", k === state.current));
  if (!state.selected.has(state.current)) {
    const item = state.items[state.current];
    const suggested = item.review ? chosenOption(item.review) : TURNS.indexOf(item.text_rotation_degrees ?? 0);
    state.selected.set(state.current, suggested >= 0 ? suggested : 0);
  }
  showSelection();
  sections()[state.current].scrollIntoView({ block: "nearest" });
}

function chosenOption(review) {
  return review.rotation_degrees === null ? LEAVE : TURNS.indexOf(review.rotation_degrees);
}

function select(k) {
  state.selected.set(state.current, (k + LEAVE + 1) % (LEAVE + 1));
  showSelection();
}

function showSelection() {
  const k = state.selected.get(state.current);
  sections()[state.current].querySelectorAll(".option").forEach((b) => {
    b.classList.toggle("selected", Number(b.dataset.option) === k);
  });
}

function showDecision(i) {
  const item = state.items[i];
  const section = sections()[i];
  section.classList.toggle("done", Boolean(item.review));
  const chosen = item.review ? chosenOption(item.review) : -1;
  section.querySelectorAll(".option").forEach((b) => b.classList.toggle("chosen", Number(b.dataset.option) === chosen));
  const r = item.review;
  section.querySelector(".decided").textContent = !r ? "" : r.rotation_degrees === null
    ? `left as it is by ${r.reviewer}` : `turned ${r.rotation_degrees}\u00b0 by ${r.reviewer} (Orientation ${r.orientation}, ${r.fixed_file})`;
}

function updateProgress() {
  const done = state.items.filter((item) => item.review).length;
  $("progress").textContent = `(${done} of ${state.items.length} decided)`;
}

async function decide() {
  if (state.pending || !state.items.length) return;
  const reviewer = $("reviewer").value.trim();
  if (!reviewer) {
    say("type your name first: it is recorded with each decision", true);
    $("reviewer").focus();
    return;
  }
  localStorage.setItem("sweepcast-reviewer", reviewer);
  const i = state.current;
  const item = state.items[i];
  const k = state.selected.get(i);
  state.pending = true;
  try {
    const response = await api(`/v1/photos/batches/${encodeURIComponent(state.job)}/review/${item.index}`, state.key, {
      method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ rotation_degrees: k === LEAVE ? null : TURNS[k], reviewer }),
    });
    state.items[i] = await response.json();
    showDecision(i);
    updateProgress();
    say(`${item.filename}: ${k === LEAVE ? "left as it is" : `turned ${TURNS[k]}\u00b0, written`}`);
    const next = state.items.findIndex((it, j) => j > i && !it.review);
    if (next >= 0) focusItem(next);
  } catch (error) {
    say(`${item.filename}: ${error.message}`, true);
  } finally {
    state.pending = false;
  }
}

document.addEventListener("keydown", (event) => {
  if (event.target instanceof HTMLInputElement) {
    if (event.key === "Enter") event.target.blur();
    return;
  }
  const keys = {
    ArrowDown: () => focusItem(state.current + 1), j: () => focusItem(state.current + 1),
    ArrowUp: () => focusItem(state.current - 1), k: () => focusItem(state.current - 1),
    ArrowRight: () => select(state.selected.get(state.current) + 1),
    ArrowLeft: () => select(state.selected.get(state.current) - 1),
    Enter: () => decide(), " ": () => decide(),
    1: () => select(0), 2: () => select(1), 3: () => select(2), 4: () => select(3), 0: () => select(LEAVE),
  };
  const action = keys[event.key];
  if (action && state.items.length) {
    event.preventDefault();
    action();
  }
});

$("reviewer").value = localStorage.getItem("sweepcast-reviewer") || "";
$("key").value = state.key;
$("key").addEventListener("change", () => {
  state.key = $("key").value.trim();
  rememberKey(state.key);
  load();
});
load();
