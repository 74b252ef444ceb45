// The lab's control page: every Thing the adapter lists, drawn from its TD alone (no per-device HTML), starting from
// the lab's state. An index (filter by name or type) jumps to each compact card; each property shows its value as
// labelled fields, live (the adapter's one SSE stream for the page; properties that are not observable are read again
// while their card is on screen); writable properties and actions get fields generated from their schema (forms.js),
// filled with the current value, with the raw JSON as an option; answers and problems are shown after each call.
// With HTTP auth on, the credentials are asked once and sent with every call, the stream included
// (it is read with fetch, which can send them; EventSource cannot).
import { $, InputError, editor, guesser, readout, unitName, unitSymbol } from "./forms.js";

const page = { auth: sessionStorage.getItem("twinmesh-auth"), challenge: null, view: null, names: [] };
const POLL_MS = 3000;  // how often a card on screen reads its properties that no stream carries
const status = (text) => { document.getElementById("status").textContent = text; };
const ops = (form) => [].concat(form.op || []);
const formFor = (affordance, op, sse = false) =>
  (affordance.forms || []).find((f) => ops(f).includes(op) && (f.subprotocol === "sse") === sse);
// An affordance's label: its title where that is short and its own, else its name (a TD's titles can be sentences,
// or the same for two actions).
const labelOf = (name, a, all = {}) => {
  const t = a.title;
  const shared = Object.entries(all).some(([n, x]) => n !== name && x.title === t);
  return t && t.length <= 28 && !shared ? t : name;
};

class NeedsCredentials extends Error {}

async function api(url, options = {}) {
  const headers = new Headers(options.headers || {});
  headers.set("X-Requested-With", "twinmesh-page");  // a 401 then names no scheme the browser would prompt for
  if (page.auth) headers.set("Authorization", page.auth);
  const r = await fetch(url, { ...options, headers });
  if (r.status === 401) {
    page.auth = null;  // wrong or missing: ask again
    sessionStorage.removeItem("twinmesh-auth");
    askCredentials(r.headers.get("WWW-Authenticate") || "Basic");
    throw new NeedsCredentials("credentials required");
  }
  return r;
}

function askCredentials(challenge) {
  page.challenge = challenge.split(" ")[0].toLowerCase().replace(/^x-page-/, "");
  const login = document.getElementById("login");
  document.getElementById("scheme").textContent = page.challenge === "bearer" ? "a bearer token" : "user and password";
  login.user.parentElement.hidden = page.challenge === "bearer";
  login.hidden = false;
  status("Credentials required");
}

document.getElementById("login").addEventListener("submit", (e) => {
  e.preventDefault();
  const f = e.target;
  page.auth = page.challenge === "bearer" ? `Bearer ${f.secret.value}` : `Basic ${btoa(`${f.user.value}:${f.secret.value}`)}`;
  sessionStorage.setItem("twinmesh-auth", page.auth);
  f.hidden = true;
  start();
});

// --- answers ------------------------------------------------------------------------------------
async function show(out, response) {
  const text = await response.text();
  out.hidden = false;
  out.dataset.ok = String(response.ok);
  out.dataset.status = String(response.status);
  let body = text;
  try { body = JSON.parse(text); } catch { /* not JSON */ }
  const label = out.dataset.label ? `${out.dataset.label}: ` : "";
  if (!response.ok && body && typeof body === "object" && "title" in body) {  // problem+json: say what it says
    out.textContent = `${label}${response.status} ${body.title}: ${body.detail || ""}${body.reason ? ` (${body.reason})` : ""}`;
  } else if (response.status === 204 || text === "") {
    out.textContent = `${label}${response.status} done`;
  } else {
    out.textContent = `${label}${response.status} ${typeof body === "string" ? body : JSON.stringify(body, null, 1)}`;
  }
}

function failed(out, err) {
  out.hidden = false;
  out.dataset.ok = "false";
  out.textContent = `${out.dataset.label ? `${out.dataset.label}: ` : ""}${err.message || err}`;
}

// --- one Thing ------------------------------------------------------------------------------------
// The Thing's name on the adapter: the last segment of its TD's own URL (its title is the Thing's to choose).
function nameOf(td) {
  const self = (td.links || []).find((l) => l.rel === "self");
  return self ? decodeURIComponent(new URL(self.href, location.href).pathname.split("/").pop()) : td.title;
}

// What kind of Thing it is, for the index and the filter: its @type, else the kind its id names
// (`urn:twinmesh:robot:ur10`), else the first words of its name it shares with another Thing (`light-left` and
// `light-right` are lights, `conveyor-belt-1` and `-2` conveyor belts); else none.
function typeOf(td, name) {
  const declared = [].concat(td["@type"] || []).map((t) => String(t).replace(/^\w+:/, ""));
  if (declared.length) return declared.join(" ");
  const urn = /^urn:[^:]+:([^:]+):/.exec(td.id || "");
  if (urn && urn[1] !== "thing") return urn[1];
  const words = name.split("-");
  for (let n = words.length - 1; n > 0; n--) {
    const stem = `${words.slice(0, n).join("-")}-`;
    if (page.names.some((other) => other !== name && other.startsWith(stem))) return stem.slice(0, -1);
  }
  return "";
}

const things = new Map();  // name -> {td, type, section, entry, values, outputs, editors, polled, visible}

function render(td) {
  const name = nameOf(td);
  const type = typeOf(td, name);
  const card = { td, name, type, values: {}, outputs: new Map(), editors: [], polled: [], visible: false };
  const links = (td.links || []).filter((l) => l.rel === "self")
    .map((l) => $("a", { href: l.href, type: l.type, title: "The Thing Description (JSON)", text: "TD" }));
  if (page.view) links.push($("a", { href: page.view, text: "3D view" }));
  const refresh = $("button", { type: "button", class: "refresh", title: "Read every property again", text: "↻" });
  refresh.addEventListener("click", () => readAll(card));
  const description = td.description ? $("p", { class: "description", title: td.description, text: td.description }) : null;
  if (description) description.addEventListener("click", () => description.classList.toggle("open"));
  const section = $("section", { class: "thing", id: `thing-${name}`, "data-thing": name, "data-type": type },
    $("header", {}, $("h2", { text: td.title === name ? name : `${td.title} (${name})` }),
      type ? $("span", { class: "type", text: type }) : null,
      $("span", { class: "links" }, ...links, refresh)),
    description);
  card.section = section;
  const props = Object.entries(td.properties || {});
  const actions = Object.entries(td.actions || {});
  const events = Object.entries(td.events || {});
  if (props.length) section.append($("div", { class: "props" }, ...props.map(([n, p]) => propertyRow(card, n, p))));
  const quick = actions.filter(([, a]) => !a.input);
  if (quick.length) {
    const answers = quick.map(([n]) => $("pre", { class: "answer", "data-action": n, "data-label": n, hidden: true }));
    section.append($("div", { class: "quick" }, $("span", { class: "kind", text: "Actions" }),
      ...quick.map(([n, a], i) => actionForm(card, n, a, answers[i]))), ...answers);
  }
  for (const [n, a] of actions.filter(([, x]) => x.input)) section.append(actionBox(card, n, a));
  if (events.length) {
    section.append($("div", { class: "events" }, $("span", { class: "kind", text: "Events" }),
      ...events.map(([n, e]) => eventRow(card, n, e))));
  }
  card.polled = props.filter(([, p]) => !p.observable && !p.writeOnly && formFor(p, "readproperty")).map(([n]) => n);
  return card;
}

function propertyRow(card, name, p) {
  const value = $("output", { class: "value", "data-thing": card.name, "data-property": name, text: "…" });
  card.outputs.set(name, { el: value, schema: p });
  const unit = unitSymbol(p);
  const shape = ["object", "array"].includes(p.type) || p.oneOf ? " structured" : "";
  const row = $("div", { class: `prop${p.observable ? " live" : ""}${shape}`, "data-property": name },
    $("span", { class: "name", title: [p.title, p.description, p.observable ? "(live)" : "(read again while on screen)"]
      .filter(Boolean).join("\n"), text: labelOf(name, p, card.td.properties) }),
    $("span", { class: "reading" }, value, unit && typeof p.type === "string" && !["object", "array"].includes(p.type)
      ? $("span", { class: "unit", title: unitName(p), text: unit }) : null));
  const write = !p.readOnly && formFor(p, "writeproperty");
  if (!write) return row;
  const structured = ["object", "array"].includes(p.type) || Boolean(p.oneOf);
  const ed = editor(p, { label: p.title || name, key: name, raw: structured });
  card.editors.push({ ed, seed: () => (schema) => (schema === p ? card.values[name] : undefined) });
  const out = $("pre", { class: "answer", "data-property": name, hidden: true });
  const button = $("button", { type: "submit", text: "Set" });
  const form = $("form", { class: "call", "data-property": name, novalidate: true }, ed.el,
    $("span", { class: "tools" }, ...ed.tools, button));
  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    await call(out, button, ed, (body) => api(write.href, { method: write["htv:methodName"] || "PUT",
      headers: { "Content-Type": "application/json" }, body }));
    if (out.dataset.ok !== "true") return;
    ed.reset();  // written: the input follows the Thing's value again
    readOne(card, name);  // not every property is observable: show what it is now
  });
  if (structured) {
    row.append($("details", { class: "edit" }, $("summary", { text: "edit" }), form, out));
  } else {
    form.classList.add("inline");
    row.append(form, out);
  }
  return row;
}

async function call(out, button, ed, send) {
  let body;
  try {
    const v = ed ? ed.get() : undefined;
    body = ed ? JSON.stringify(v ?? null) : undefined;
  } catch (err) {
    if (err instanceof InputError) { failed(out, err); return; }
    throw err;
  }
  out.hidden = false;
  out.dataset.ok = "";
  out.textContent = `${out.dataset.label ? `${out.dataset.label}: ` : ""}…`;
  button.disabled = true;
  try {
    await show(out, await send(body));
  } catch (err) { failed(out, err); } finally { button.disabled = false; }
}

function actionForm(card, name, a, out, ed = null) {
  const invoke = formFor(a, "invokeaction");
  const button = $("button", { type: "submit", title: [a.title, a.description].filter(Boolean).join("\n"),
    text: labelOf(name, a, card.td.actions) });
  // novalidate: the Thing judges the input (its 400 names the field), not the browser
  const form = $("form", { class: "call", "data-action": name, novalidate: true }, ed ? ed.el : null,
    ed ? $("span", { class: "tools" }, ...ed.tools, button) : button);
  form.addEventListener("submit", (e) => {
    e.preventDefault();
    call(out, button, ed, (body) => api(invoke.href, { method: invoke["htv:methodName"] || "POST",
      headers: body === undefined ? {} : { "Content-Type": "application/json" }, body }));
  });
  return form;
}

function actionBox(card, name, a) {
  const structured = ["object", "array"].includes(a.input.type) || Boolean(a.input.oneOf);
  const ed = editor(a.input, { label: a.title || name, key: name, raw: structured });
  const guess = () => guesser(card.values, card.td.properties || {}, name);
  card.editors.push({ ed, seed: guess });
  const out = $("pre", { class: "answer", "data-action": name, hidden: true });
  const summary = $("summary", { title: a.description },
    $("span", { class: "name", text: labelOf(name, a, card.td.actions) }),
    a.description ? $("span", { class: "hint", text: a.description }) : null);
  return $("details", { class: "action", "data-action": name }, summary, actionForm(card, name, a, out, ed), out);
}

function eventRow(card, name, e) {
  const last = $("output", { class: "last", "data-event": name, text: "–" });
  return $("details", { class: "event", "data-event": name },
    $("summary", { title: e.description }, $("span", { class: "name", text: labelOf(name, e, card.td.events) }), " ", last),
    $("ol", { class: "log", "data-thing": card.name, "data-event": name }));
}

// --- values -----------------------------------------------------------------------------------------
const dirty = new Set();  // cards with values not yet drawn (drawn once per frame, however fast they come)

function setValue(card, name, value) {
  card.values[name] = value;
  if (!dirty.size) requestAnimationFrame(draw);
  dirty.add(card);
  (card.changed ||= new Set()).add(name);
}

function draw() {
  for (const card of dirty) {
    for (const name of card.changed) {
      const out = card.outputs.get(name);
      if (!out) continue;
      const where = (d) => d.parentElement?.closest("[data-key]")?.dataset.key ?? "";
      const open = [...out.el.querySelectorAll("details[open]")].map(where);
      out.el.replaceChildren(readout(out.schema, card.values[name], 0, name));
      for (const d of out.el.querySelectorAll("details")) {  // keep a folded value open while it changes
        if (open.includes(where(d))) d.open = true;
      }
    }
    card.changed.clear();
    for (const { ed, seed } of card.editors) ed.seed(seed());
  }
  dirty.clear();
}

async function readAll(card) {
  const all = (card.td.forms || []).find((f) => ops(f).includes("readallproperties"));
  if (!all) { await Promise.all(Object.keys(card.td.properties || {}).map((n) => readOne(card, n))); return; }
  try {
    const r = await api(all.href, { headers: { Accept: "application/json" } });
    if (r.ok) for (const [n, v] of Object.entries(await r.json())) setValue(card, n, v);
  } catch { /* it left or restarts: the stream says so */ }
}

async function readOne(card, name) {
  const read = formFor((card.td.properties || {})[name] || {}, "readproperty");
  if (!read) return;
  try {
    const r = await api(read.href);
    if (r.ok) setValue(card, name, await r.json());
  } catch { /* as above */ }
}

async function poll() {
  if (document.visibilityState !== "visible") return;
  await Promise.all([...things.values()].filter((c) => c.visible && c.polled.length && !c.section.hidden)
    .map(async (card) => {
      const all = (card.td.forms || []).find((f) => ops(f).includes("readmultipleproperties"));
      if (!all) return Promise.all(card.polled.map((n) => readOne(card, n)));
      try {
        const r = await api(`${all.href}?names=${card.polled.map(encodeURIComponent).join(",")}`);
        if (r.ok) for (const [n, v] of Object.entries(await r.json())) setValue(card, n, v);
      } catch { /* as above */ }
      return undefined;
    }));
}

// --- live updates -----------------------------------------------------------------------------------
async function follow(url, onEvent, onOpen = () => {}, onLost = () => {}) {
  for (;;) {
    try {
      const r = await api(url, { headers: { Accept: "text/event-stream" } });
      if (!r.ok) throw new Error(`${r.status}`);
      onOpen();  // the server registered the stream before its headers went out
      const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
      let buffer = "";
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buffer += value.replace(/\r\n/g, "\n");
        let end;
        while ((end = buffer.indexOf("\n\n")) >= 0) {
          const frame = buffer.slice(0, end);
          buffer = buffer.slice(end + 2);
          let event = "message"; const data = [];
          for (const line of frame.split("\n")) {
            if (line.startsWith("event:")) event = line.slice(6).trim();
            else if (line.startsWith("data:")) data.push(line.slice(5).replace(/^ /, ""));
          }
          if (data.length) onEvent(event, data.join("\n"));
        }
      }
    } catch (err) {
      if (err instanceof NeedsCredentials) return;
    }
    onLost();
    await new Promise((done) => setTimeout(done, 2000));  // the adapter restarts: again, and read the state anew
    things.forEach(readAll);
  }
}

function update(name, data) {  // one notification of the lab stream: `<thing>/<kind>/<name>`
  const [thing, kind, affordance] = name.split("/");
  const card = things.get(thing);
  if (!card) return;
  let value = data;
  try { value = JSON.parse(data); } catch { /* not JSON: shown as it came */ }
  if (kind === "properties") setValue(card, affordance, value);
  else if (kind === "events") {
    const box = card.section.querySelector(`details[data-event="${CSS.escape(affordance)}"]`);
    if (!box) return;
    const text = typeof value === "object" ? JSON.stringify(value) : String(value);
    box.querySelector("output.last").textContent = text;
    const log = box.querySelector("ol.log");
    log.prepend($("li", {}, $("time", { text: new Date().toLocaleTimeString() }), " ", text));
    while (log.children.length > 50) log.lastChild.remove();
  }
}

// --- the index and its filter ---------------------------------------------------------------------------
function indexEntry(card) {
  const link = $("a", { href: `#thing-${card.name}`, "data-thing": card.name },
    $("span", { class: "n", text: card.name }),
    card.type && !card.name.startsWith(card.type) ? $("span", { class: "t", text: card.type }) : null);
  link.addEventListener("click", (e) => {  // jump, and say where we landed
    e.preventDefault();
    history.replaceState(null, "", `#thing-${card.name}`);
    card.section.scrollIntoView({ block: "start" });
    card.section.classList.remove("flash");
    void card.section.offsetWidth;
    card.section.classList.add("flash");
  });
  return $("li", { "data-thing": card.name }, link);
}

function applyFilter() {
  const words = document.getElementById("filter").value.trim().toLowerCase().split(/\s+/).filter(Boolean);
  let shown = 0;
  for (const card of things.values()) {
    const hay = `${card.name} ${card.td.title || ""} ${card.type}`.toLowerCase();
    const match = words.every((w) => hay.includes(w));
    card.section.hidden = !match;
    card.entry.hidden = !match;
    shown += match;
  }
  document.getElementById("count").textContent = words.length ? `${shown} of ${things.size}` : `${things.size}`;
  document.getElementById("nomatch").hidden = shown > 0;
  const types = [...new Set([...things.values()].map((c) => c.type).filter(Boolean))].sort();
  const chips = document.getElementById("types");
  if (chips.childElementCount !== types.length) {
    chips.replaceChildren(...types.map((t) => {
      const chip = $("button", { type: "button", "data-type": t, text: t });
      chip.addEventListener("click", () => {
        const input = document.getElementById("filter");
        input.value = input.value.trim().toLowerCase() === t ? "" : t;
        applyFilter();
      });
      return chip;
    }));
  }
  const q = words.join(" ");
  for (const chip of chips.children) chip.setAttribute("aria-pressed", String(chip.dataset.type === q));
}

const onScreen = new IntersectionObserver((seen) => {
  for (const s of seen) {
    const card = things.get(s.target.dataset.thing);
    if (card) card.visible = s.isIntersecting;
  }
});

function place(td) {
  if (!page.names.includes(nameOf(td))) page.names.push(nameOf(td));
  const card = render(td);
  const old = things.get(card.name);
  const main = document.getElementById("things");
  const list = document.getElementById("index");
  card.entry = indexEntry(card);
  if (old) {
    onScreen.unobserve(old.section);
    old.section.replaceWith(card.section);
    old.entry.replaceWith(card.entry);
  } else {
    const after = [...things.keys()].sort().find((t) => t > card.name);
    main.insertBefore(card.section, after ? things.get(after).section : null);
    list.insertBefore(card.entry, after ? things.get(after).entry : null);
  }
  things.set(card.name, card);
  onScreen.observe(card.section);
  applyFilter();
  return readAll(card);
}

async function directory(kind, data) {
  const { title } = JSON.parse(data);
  if (kind === "thing_deleted") {
    const card = things.get(title);
    if (card) { card.section.classList.add("gone"); card.entry.classList.add("gone"); }
    return;
  }
  place(await api(`/${title}`).then((x) => x.json()));
  status(`${things.size} Things · live`);
}

document.getElementById("filter").addEventListener("input", applyFilter);
document.getElementById("filter").addEventListener("keydown", (e) => {
  if (e.key === "Enter") {  // Enter goes to the first Thing that matches
    e.preventDefault();
    document.querySelector("#index li:not([hidden]) a")?.click();
  } else if (e.key === "Escape") {
    e.target.value = "";
    applyFilter();
  }
});
document.getElementById("find").addEventListener("click", () => {
  window.scrollTo({ top: 0 });
  document.getElementById("filter").focus();
});
document.addEventListener("keydown", (e) => {  // "/" finds a Thing, as in most consoles
  if (e.key === "/" && !/^(INPUT|TEXTAREA|SELECT)$/.test(document.activeElement?.tagName || "")) {
    e.preventDefault();
    document.getElementById("filter").focus();
  }
});

async function start() {
  try {
    const config = await fetch("/_ui/config.json").then((r) => (r.ok ? r.json() : {})).catch(() => ({}));
    page.view = config.view || null;
    if (page.view) document.getElementById("views").replaceChildren($("a", { href: page.view, text: "3D view of the lab" }));
    const r = await api("/things");
    const tds = await r.json();
    page.names = tds.map(nameOf);
    const secured = tds.map((td) => (td.securityDefinitions || {})[[].concat(td.security || [])[0]])
      .find((d) => d && d.scheme && d.scheme !== "nosec");
    if (secured && !page.auth) {  // the TDs say what to send: ask before any call is refused
      askCredentials(secured.scheme);
      return;
    }
    const loaded = Promise.all(tds.map(place)).then(() => new Promise((done) => requestAnimationFrame(done)));
    status(`${tds.length} Things`);
    if (location.hash) document.getElementById(decodeURIComponent(location.hash.slice(1)))?.scrollIntoView();
    setInterval(poll, POLL_MS);
    // one stream for the whole page: a browser opens at most six connections to a host
    follow("/_lab/stream", (name, data) => {
      if (name.startsWith("/directory/events/")) directory(name.split("/").pop(), data);
      else update(name, data);
    }, () => {  // live, and showing the state
      loaded.then(() => { document.body.dataset.ready = "true"; status(`${things.size} Things · live`); });
    }, () => status(`${things.size} Things · reconnecting…`));
  } catch (err) {
    if (!(err instanceof NeedsCredentials)) status(`Cannot load the Things: ${err.message || err}`);
  }
}

start();
