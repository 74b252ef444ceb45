// The lab's control page: every Thing the adapter lists, drawn from its TD alone (no per-device HTML).
// Properties show their live value (the adapter's own SSE, one stream for the page), writable ones and actions get a
// form generated from their schema, answers and problems are shown after each call, events are logged.
// With HTTP auth on, the credentials are asked once and sent with every call, the streams included
// (they are read with fetch, which can send them; EventSource cannot).

const page = { auth: sessionStorage.getItem("twinmesh-auth"), challenge: null };
const $ = (tag, attrs = {}, ...children) => {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k === "text") el.textContent = v; else el.setAttribute(k, v === true ? "" : v);
  }
  el.append(...children.filter((c) => c !== null && c !== undefined));
  return el;
};
const status = (text) => { document.getElementById("status").textContent = text; };
const ops = (form) => [].concat(form.op || []);
const formFor = (affordance, op, sse = false) =>
  (affordance.forms || []).find((f) => ops(f).includes(op) && (f.subprotocol === "sse") === sse);
const unitOf = (schema) => (schema && schema.unit ? String(schema.unit).replace(/^qudt:/, "") : "");

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
  out.dataset.ok = String(response.ok);
  out.dataset.status = String(response.status);
  let body = text;
  try { body = JSON.parse(text); } catch { /* not JSON */ }
  if (!response.ok && body && typeof body === "object" && "title" in body) {
    out.textContent = `${response.status} ${body.title}: ${body.detail || ""}${body.reason ? ` (${body.reason})` : ""}`;
  } else if (response.status === 204) {
    out.textContent = `${response.status} done`;
  } else {
    out.textContent = `${response.status} ${typeof body === "string" ? body : JSON.stringify(body, null, 1)}`;
  }
}

// --- forms from data schemas ----------------------------------------------------------------------
// field(schema, label) -> {el, get(), set(value)}: the value as JSON, or undefined when left empty.
function field(schema = {}, label = "value") {
  const hint = [unitOf(schema), schema.minimum !== undefined ? `≥ ${schema.minimum}` : "",
    schema.maximum !== undefined ? `≤ ${schema.maximum}` : ""].filter(Boolean).join(" ");
  const wrap = (input) => $("label", {}, $("span", { text: schema.title || label }), input,
    hint ? $("span", { class: "hint", text: hint }) : null);
  if (schema.enum) {
    const select = $("select", { name: label }, ...schema.enum.map((v) => $("option", { value: JSON.stringify(v), text: String(v) })));
    return { el: wrap(select), get: () => JSON.parse(select.value), set: (v) => { select.value = JSON.stringify(v); } };
  }
  if (schema.type === "boolean") {
    const select = $("select", { name: label }, $("option", { value: "true", text: "true" }), $("option", { value: "false", text: "false" }));
    return { el: wrap(select), get: () => select.value === "true", set: (v) => { select.value = String(v); } };
  }
  if (schema.type === "number" || schema.type === "integer") {
    const input = $("input", { type: "number", name: label, min: schema.minimum, max: schema.maximum,
      step: schema.type === "integer" ? (schema.multipleOf || 1) : (schema.multipleOf || "any") });
    const start = schema.default ?? ((schema.minimum ?? 0) <= 0 && 0 <= (schema.maximum ?? 0) ? 0 : schema.minimum);
    if (start !== undefined) input.value = start;
    return { el: wrap(input), get: () => (input.value === "" ? undefined : Number(input.value)), set: (v) => { input.value = v; } };
  }
  if (schema.type === "string" && !schema.oneOf) {
    const input = $("input", { type: "text", name: label, value: schema.default });
    return { el: wrap(input), get: () => (input.value === "" ? undefined : input.value), set: (v) => { input.value = v; } };
  }
  if (schema.type === "object" && schema.properties && !schema.oneOf) {
    const parts = Object.entries(schema.properties).map(([k, s]) => [k, field(s, k)]);
    const set = $("fieldset", { "data-field": label }, $("legend", { text: schema.title || label }), ...parts.map(([, f]) => f.el));
    return {
      el: set,
      get: () => Object.fromEntries(parts.map(([k, f]) => [k, f.get()]).filter(([, v]) => v !== undefined)),
      set: (v) => parts.forEach(([k, f]) => v && k in v && f.set(v[k])),
    };
  }
  if (schema.type === "array" && schema.items && !Array.isArray(schema.items) && schema.minItems === schema.maxItems
      && schema.minItems > 0 && schema.minItems <= 8) {
    const parts = Array.from({ length: schema.minItems }, (_, i) => field(schema.items, `${label}[${i}]`));
    const set = $("fieldset", { "data-field": label }, $("legend", { text: schema.title || label }), ...parts.map((f) => f.el));
    return { el: set, get: () => parts.map((f) => f.get()), set: (v) => Array.isArray(v) && parts.forEach((f, i) => f.set(v[i])) };
  }
  const area = $("textarea", { name: label, placeholder: "JSON" });  // oneOf, free objects, long arrays
  return { el: wrap(area), get: () => (area.value.trim() === "" ? undefined : JSON.parse(area.value)),
           set: (v) => { area.value = JSON.stringify(v); } };
}

// --- one Thing ------------------------------------------------------------------------------------
function propertyRow(td, name, p) {
  const value = $("output", { class: "value", "data-thing": nameOf(td), "data-property": name, text: "…" });
  const row = $("div", { class: "affordance property", "data-property": name },
    $("span", { class: "name", text: p.title || name }), " ", value, " ", $("span", { class: "unit", text: unitOf(p) }));
  const read = formFor(p, "readproperty");
  if (read) api(read.href).then(async (r) => { if (r.ok) value.textContent = await r.text(); }).catch(() => {});
  const write = formFor(p, "writeproperty");
  if (write) {
    const f = field(p, name);
    const out = $("pre", { class: "answer", hidden: true });
    const form = $("form", { class: "call", "data-property": name, novalidate: true }, f.el,
      $("button", { type: "submit", text: "Write" }));
    form.addEventListener("submit", async (e) => {
      e.preventDefault();
      out.hidden = false;
      try {
        await show(out, await api(write.href, { method: write["htv:methodName"] || "PUT",
          headers: { "Content-Type": "application/json" }, body: JSON.stringify(f.get() ?? null) }));
      } catch (err) { out.dataset.ok = "false"; out.textContent = String(err.message || err); }
    });
    row.append(form, out);
  }
  return row;
}

function actionRow(td, name, a) {
  const invoke = formFor(a, "invokeaction");
  const f = a.input ? field(a.input, "input") : null;
  const out = $("pre", { class: "answer", hidden: true });
  // novalidate: the Thing judges the input (its 400 names the field), not the browser
  const form = $("form", { class: "call", "data-action": name, novalidate: true }, f ? f.el : null,
    $("button", { type: "submit", text: a.title || name }));
  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    out.hidden = false;
    out.textContent = "…";
    try {
      const body = f ? JSON.stringify(f.get() ?? null) : undefined;
      await show(out, await api(invoke.href, { method: invoke["htv:methodName"] || "POST",
        headers: body === undefined ? {} : { "Content-Type": "application/json" }, body }));
    } catch (err) { out.dataset.ok = "false"; out.textContent = String(err.message || err); }
  });
  return $("div", { class: "affordance action", "data-action": name },
    $("span", { class: "name", text: name }), a.description ? $("div", { class: "hint", text: a.description }) : null, form, out);
}

function eventRow(td, name, e) {
  return $("div", { class: "affordance event", "data-event": name }, $("span", { class: "name", text: e.title || name }),
    $("ol", { class: "log", "data-thing": nameOf(td), "data-event": name }));
}

// The Thing's name on the adapter: the last segment of its TD's own URL (its title is the Thing's to choose).
function nameOf(td) {
  const self = (td.links || []).find((l) => l.rel === "self");
  return self ? decodeURIComponent(new URL(self.href, location.href).pathname.split("/").pop()) : td.title;
}

function render(td) {
  const links = (td.links || []).map((l) => $("a", { href: l.href, type: l.type, text: l.rel === "self" ? "TD" : (l.href.split("/").pop() || l.rel) }));
  if (page.view) links.push($("a", { href: page.view, text: "3D view" }));
  const name = nameOf(td);
  const section = $("section", { class: "thing", id: `thing-${name}`, "data-thing": name },
    $("h2", { text: td.title === name ? name : `${td.title} (${name})` }), td.description ? $("p", { class: "description", text: td.description }) : null,
    $("div", { class: "links" }, ...links));
  const props = Object.entries(td.properties || {}), actions = Object.entries(td.actions || {}), events = Object.entries(td.events || {});
  if (props.length) section.append($("h3", { text: "Properties" }), ...props.map(([n, p]) => propertyRow(td, n, p)));
  if (actions.length) section.append($("h3", { text: "Actions" }), ...actions.map(([n, a]) => actionRow(td, n, a)));
  if (events.length) section.append($("h3", { text: "Events" }), ...events.map(([n, e]) => eventRow(td, n, e)));
  return section;
}

// --- live updates -----------------------------------------------------------------------------------
async function follow(url, onEvent, stop, onOpen = () => {}) {
  while (!stop.stopped) {
    try {
      const r = await api(url, { headers: { Accept: "text/event-stream" } });
      if (!r.ok) throw new Error(`${r.status}`);
      onOpen();  // the server registered the stream before its headers went out
      const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
      let buffer = "";
      for (;;) {
        const { value, done } = await reader.read();
        if (done || stop.stopped) break;
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
    await new Promise((done) => setTimeout(done, 2000));  // the Thing left, or the adapter restarts
  }
}

function update(name, data) {  // one notification of the lab stream: `<thing>/<kind>/<name>`
  const [thing, kind, affordance] = name.split("/");
  const section = shown.get(thing)?.section;
  if (!section) return;
  if (kind === "properties") {
    const out = section.querySelector(`output[data-property="${CSS.escape(affordance)}"]`);
    if (out) out.textContent = data;
  } else if (kind === "events") {
    const log = section.querySelector(`ol[data-event="${CSS.escape(affordance)}"]`);
    if (!log) return;
    log.prepend($("li", { text: `${new Date().toLocaleTimeString()} ${data}` }));
    while (log.children.length > 50) log.lastChild.remove();
  }
}

// --- the page -------------------------------------------------------------------------------------
const shown = new Map();  // name -> {section}

function place(td) {
  const name = nameOf(td);
  const old = shown.get(name);
  const section = render(td);
  const main = document.getElementById("things");
  if (old) old.section.replaceWith(section);
  else {
    const after = [...shown.keys()].sort().find((t) => t > name);
    main.insertBefore(section, after ? shown.get(after).section : null);
  }
  shown.set(name, { section });
}

async function directory(kind, data) {
  const { title } = JSON.parse(data);
  if (kind === "thing_deleted") { shown.get(title)?.section.classList.add("gone"); return; }
  place(await api(`/${title}`).then((x) => x.json()));
  status(`${shown.size} Things`);
}

async function start() {
  try {
    const config = await fetch("/_ui/config.json").then((r) => (r.ok ? r.json() : {})).catch(() => ({}));
    page.view = config.view || null;
    if (page.view) document.getElementById("views").append($("a", { href: page.view, text: "3D view of the lab" }));
    const r = await api("/things");
    const tds = await r.json();
    const secured = tds.map((td) => (td.securityDefinitions || {})[[].concat(td.security || [])[0]])
      .find((d) => d && d.scheme && d.scheme !== "nosec");
    if (secured && !page.auth) {  // the TDs say what to send: ask before any call is refused
      askCredentials(secured.scheme);
      return;
    }
    tds.forEach(place);
    status(`${tds.length} Things`);
    // one stream for the whole page: a browser opens at most six connections to a host
    follow("/_lab/stream", (name, data) => {
      if (name.startsWith("/directory/events/")) directory(name.split("/").pop(), data);
      else update(name, data);
    }, { stopped: false }, () => { document.body.dataset.ready = "true"; });
  } catch (err) {
    if (!(err instanceof NeedsCredentials)) status(`Cannot load the Things: ${err.message || err}`);
  }
}

start();
