// Data schemas (WoT TD DataSchema, a JSON Schema subset) to input fields and to labelled read-outs.
// No page state and no network here: the page (app.js) decides what to fill in and where to send it.
//
// field(schema, opts) -> {el, get(), set(value), seed(fn)}: get() is the value as JSON, or undefined when an
// optional field is left empty (the Thing judges what is missing: its 400 names the field, not the browser).

export const $ = (tag, attrs = {}, ...children) => {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k === "text") el.textContent = v; else el.setAttribute(k, v === true ? "" : v);
  }
  el.append(...children.filter((c) => c !== null && c !== undefined && c !== false));
  return el;
};

// --- units and numbers -------------------------------------------------------------------------------
const SYMBOLS = { MilliM: "mm", M: "m", DEG: "°", "DEG-PER-SEC": "°/s", PERCENT: "%", SEC: "s", LUX: "lx", K: "K",
  "MilliM-PER-MIN": "mm/min", "M-PER-SEC": "m/s", RAD: "rad", UNITLESS: "", NUM: "" };
export const unitName = (schema) => (schema && schema.unit ? String(schema.unit).replace(/^qudt:/, "") : "");
export const unitSymbol = (schema) => { const u = unitName(schema); return u in SYMBOLS ? SYMBOLS[u] : u; };

export function fmt(v) {
  if (typeof v !== "number" || !Number.isFinite(v) || Number.isInteger(v)) return String(v);
  const a = Math.abs(v);
  const text = a >= 100 ? v.toFixed(1) : a >= 1 ? v.toFixed(2) : a >= 0.001 ? v.toPrecision(3) : v.toExponential(2);
  return text.includes("e") ? text : text.replace(/\.?0+$/, "") || "0";
}

function bounds(schema) {
  const lo = schema.minimum ?? schema.exclusiveMinimum, hi = schema.maximum ?? schema.exclusiveMaximum;
  if (lo !== undefined && hi !== undefined) return `${fmt(lo)} … ${fmt(hi)}`;
  if (lo !== undefined) return `≥ ${fmt(lo)}`;
  if (hi !== undefined) return `≤ ${fmt(hi)}`;
  return "";
}

// What a fixed-length array's items are called: x/y/z, r/g/b where the schema says so, else 1, 2, 3...
export function itemLabels(schema, n, key = "") {
  const text = `${key} ${schema.title || ""} ${schema.description || ""}`;
  if (n === 3 && /\bx\W+y\W+z\b|position|centre|center|offset|origin|extent/i.test(text)) return ["x", "y", "z"];
  if (n === 3 && /\brgb\b|colou?r/i.test(text)) return ["r", "g", "b"];
  if (n === 4 && /\bqx\W+qy\W+qz\W+qw\b/i.test(text)) return ["qx", "qy", "qz", "qw"];
  return Array.from({ length: n }, (_, i) => String(i + 1));
}

const fixedLength = (schema) => schema.items && !Array.isArray(schema.items) && schema.minItems !== undefined
  && schema.minItems === schema.maxItems && schema.minItems > 0 && schema.minItems <= 8;
const kindOf = (schema) => [].concat(schema.type || [])[0];

// The value a field starts from when neither the Thing nor the user gave one: the schema's default, else for a
// required number 0 brought into its bounds (so that the form is valid as it stands).
function startValue(schema, required) {
  if (schema.default !== undefined) return schema.default;
  if (schema.const !== undefined) return schema.const;
  if (schema.enum) return required ? schema.enum[0] : undefined;
  const kind = kindOf(schema);
  if (kind === "boolean") return false;
  if ((kind === "number" || kind === "integer") && required) {
    return Math.min(Math.max(0, schema.minimum ?? -Infinity), schema.maximum ?? Infinity);
  }
  return undefined;
}

// --- fields ------------------------------------------------------------------------------------------
function labelled(schema, opts, input) {
  const unit = unitSymbol(schema), range = bounds(schema);
  return $("label", { class: "field", "data-key": opts.key, title: schema.description },
    $("span", { class: "label", text: `${schema.title || opts.label}${opts.required ? "" : " (optional)"}` }),
    $("span", { class: "control" }, input, unit ? $("span", { class: "unit", title: unitName(schema), text: unit }) : null),
    range ? $("span", { class: "hint", text: range }) : null);
}

export function field(schema = {}, opts = {}) {
  opts = { label: "value", key: "value", required: true, ...opts };
  const name = opts.path || opts.key;
  const seed = (self) => (fn) => { const v = fn(schema); if (v !== undefined) self.set(v); };
  const kind = kindOf(schema);
  const alternatives = schema.oneOf || schema.anyOf;
  if (alternatives && alternatives.length) return choice(schema, alternatives, opts);
  if (schema.enum) {
    const options = schema.enum.map((v) => $("option", { value: JSON.stringify(v), text: String(v) }));
    const select = $("select", { name }, opts.required ? null : $("option", { value: "", text: "—" }), ...options);
    const self = { el: labelled(schema, opts, select),
      get: () => (select.value === "" ? undefined : JSON.parse(select.value)),
      set: (v) => { select.value = v === undefined ? "" : JSON.stringify(v); } };
    self.seed = seed(self);
    self.set(startValue(schema, opts.required));
    return self;
  }
  if (kind === "boolean") {
    const box = $("input", { type: "checkbox", name });
    const self = { el: labelled(schema, opts, box), get: () => box.checked, set: (v) => { box.checked = Boolean(v); } };
    self.el.classList.add("check");
    self.seed = seed(self);
    self.set(startValue(schema, opts.required));
    return self;
  }
  if (kind === "number" || kind === "integer") {
    const input = $("input", { type: "number", name, min: schema.minimum, max: schema.maximum, inputmode: "decimal",
      step: schema.multipleOf || (kind === "integer" ? 1 : "any"), placeholder: bounds(schema) || "number" });
    const self = { el: labelled(schema, opts, input),
      get: () => (input.value === "" ? undefined : Number(input.value)),
      set: (v) => { input.value = typeof v === "number" ? String(kind === "integer" ? v : Number(v.toPrecision(6))) : ""; } };
    self.seed = seed(self);
    self.set(startValue(schema, opts.required));
    return self;
  }
  if (kind === "string") {
    const input = $("input", { type: "text", name, pattern: schema.pattern, maxlength: schema.maxLength,
      placeholder: schema.pattern ? `matches ${schema.pattern}` : schema.format || "" });
    const self = { el: labelled(schema, opts, input),
      get: () => (input.value === "" ? undefined : input.value), set: (v) => { input.value = v ?? ""; } };
    self.seed = seed(self);
    self.set(startValue(schema, opts.required));
    return self;
  }
  if (kind === "object" && schema.properties) return group(schema, opts);
  if (kind === "array" && schema.items && !Array.isArray(schema.items)) {
    return fixedLength(schema) ? tuple(schema, opts) : list(schema, opts);
  }
  return rawField(schema, opts);  // free objects, tuples, anything the schema leaves open
}

function legend(schema, opts) {
  const unit = unitSymbol(schema);
  return $("legend", { title: schema.description, text: `${schema.title || opts.label}${unit ? ` (${unit})` : ""}` });
}

function group(schema, opts) {
  const required = new Set(schema.required || []);
  const parts = Object.entries(schema.properties).map(([k, s]) =>
    [k, field(s, { label: k, key: k, path: opts.top ? k : `${opts.path || opts.key}.${k}`, required: required.has(k) })]);
  const el = $("fieldset", { class: "group", "data-field": opts.key }, opts.top ? null : legend(schema, opts),
    ...parts.map(([, f]) => f.el));
  return {
    el,
    get: () => {
      const out = Object.fromEntries(parts.map(([k, f]) => [k, f.get()]).filter(([, v]) => v !== undefined));
      return Object.keys(out).length || opts.required ? out : undefined;
    },
    set: (v) => { if (v && typeof v === "object") parts.forEach(([k, f]) => k in v && f.set(v[k])); },
    seed(fn) {
      const v = fn(schema);
      if (v !== undefined) this.set(v);
      // a part the whole did not fill: from what its own name says (`panAngle` from `panPosition`)
      parts.forEach(([k, f]) => { if (!v || !(k in v)) f.seed((s, key) => fn(s, key ?? k)); });
    },
  };
}

function tuple(schema, opts) {
  const labels = itemLabels(schema, schema.minItems, opts.key);
  const parts = labels.map((l, i) => field(schema.items, { label: l, key: String(i), path: `${opts.path || opts.key}[${i}]` }));
  const el = $("fieldset", { class: "group tuple", "data-field": opts.key }, legend(schema, opts), ...parts.map((f) => f.el));
  const self = {
    el,
    get: () => { const v = parts.map((f) => f.get()); return v.every((x) => x === undefined) && !opts.required ? undefined : v; },
    set: (v) => { if (Array.isArray(v)) parts.forEach((f, i) => f.set(v[i])); },
  };
  self.seed = (fn) => { const v = fn(schema); if (v !== undefined) self.set(v); };
  return self;
}

function list(schema, opts) {
  const rows = $("div", { class: "rows" });
  const items = [];
  const add = $("button", { type: "button", class: "add", text: "+ add" });
  const el = $("fieldset", { class: "group list", "data-field": opts.key }, legend(schema, opts), rows, add);
  const limits = () => {
    add.disabled = schema.maxItems !== undefined && items.length >= schema.maxItems;
    items.forEach((it) => { it.remove.disabled = items.length <= (schema.minItems || 0); });
    items.forEach((it, i) => { it.f.el.querySelector(".label").textContent = `${i + 1}`; });
  };
  const push = (value) => {
    const f = field(schema.items, { label: String(items.length + 1), key: String(items.length),
      path: `${opts.path || opts.key}[]` });
    const remove = $("button", { type: "button", class: "remove", title: "Remove this item", text: "×" });
    const row = $("div", { class: "row" }, f.el, remove);
    const it = { f, remove, row };
    remove.addEventListener("click", () => {
      items.splice(items.indexOf(it), 1);
      row.remove();
      limits();
      el.dispatchEvent(new Event("input", { bubbles: true }));
    });
    if (value !== undefined) f.set(value);
    items.push(it);
    rows.append(row);
    limits();
  };
  add.addEventListener("click", () => { push(undefined); el.dispatchEvent(new Event("input", { bubbles: true })); });
  for (let i = 0; i < (schema.minItems || 0); i++) push(undefined);
  const self = {
    el,
    get: () => (items.length || opts.required ? items.map((it) => it.f.get()) : undefined),
    set: (v) => {
      if (!Array.isArray(v)) return;
      items.splice(0).forEach((it) => it.row.remove());
      v.forEach((x) => push(x));
      limits();
    },
  };
  self.seed = (fn) => { const v = fn(schema); if (v !== undefined) self.set(v); };
  return self;
}

// oneOf / anyOf: a choice of the alternatives (by their titles), the chosen one's fields below it.
function choice(schema, alternatives, opts) {
  const variants = alternatives.map((s, i) => ({ s, f: field(s, opts), title: s.title || `option ${i + 1}` }));
  const select = $("select", { name: `${opts.path || opts.key}:variant`, class: "variant" },
    ...variants.map((v, i) => $("option", { value: String(i), text: v.title })));
  const body = $("div", { class: "variant-body" });
  const show = () => body.replaceChildren(variants[Number(select.value)].f.el);
  select.addEventListener("change", show);
  show();
  const el = $("div", { class: "choice", "data-field": opts.key },
    $("label", { class: "field" }, $("span", { class: "label", text: schema.title || (opts.top ? "target" : opts.label) }),
      select), body);
  const covers = (s, v) => {
    if (v === null || typeof v !== "object" || Array.isArray(v)) return kindOf(s) === (Array.isArray(v) ? "array" : typeof v);
    const keys = Object.keys(s.properties || {});
    return (s.required || []).every((k) => k in v) && Object.keys(v).every((k) => keys.includes(k));
  };
  return {
    el,
    get: () => variants[Number(select.value)].f.get(),
    set: (v) => {
      const i = variants.findIndex((x) => covers(x.s, v));
      if (i < 0) return;
      select.value = String(i);
      show();
      variants[i].f.set(v);
    },
    seed: (fn) => variants.forEach((v) => v.f.seed(fn)),
  };
}

function rawField(schema, opts) {
  const area = $("textarea", { name: opts.path || opts.key, placeholder: "JSON", rows: 2, spellcheck: "false" });
  const self = { el: labelled(schema, opts, area),
    get: () => (area.value.trim() === "" ? undefined : parseJSON(area.value, opts.path || opts.key)),
    set: (v) => { area.value = v === undefined ? "" : JSON.stringify(v); } };
  self.seed = (fn) => { const v = fn(schema); if (v !== undefined) self.set(v); };
  return self;
}

export class InputError extends Error {}

function parseJSON(text, where) {
  try { return JSON.parse(text); } catch (err) { throw new InputError(`${where}: not valid JSON (${err.message})`); }
}

// --- an input with its raw JSON alternative -------------------------------------------------------------
// editor(schema) -> {el, tools, get(), set(v), seed(fn), edited}: the generated fields, or (toggle) a JSON text of
// the same value; `edited` is true once the user changed something, so that live values no longer overwrite it.
export function editor(schema, opts = {}) {
  const f = field(schema, { label: opts.label || "input", key: opts.key || "input", required: true, top: true });
  const area = $("textarea", { class: "json", name: "json", rows: 4, spellcheck: "false", hidden: true,
    "aria-label": "the input as JSON" });
  const raw = $("button", { type: "button", class: "raw", "aria-pressed": "false", title: "Edit the input as JSON",
    text: "{ } JSON" });
  const undo = $("button", { type: "button", class: "undo", hidden: true, title: "Back to the Thing's current values",
    text: "↺ current" });
  const el = $("div", { class: "editor" }, f.el, area);
  const self = {
    el, tools: opts.raw === false ? [undo] : [undo, raw], edited: false, lastSeed: null,
    json: () => raw.getAttribute("aria-pressed") === "true",
    get: () => (self.json() ? parseJSON(area.value, "JSON") : f.get()),
    set: (v) => { f.set(v); if (self.json()) area.value = JSON.stringify(v, null, 1); },
    seed: (fn) => {
      self.lastSeed = fn;
      if (self.edited) return;
      f.seed(fn);
      if (self.json()) area.value = JSON.stringify(f.get(), null, 1);
    },
    reset: () => {
      self.edited = false;
      undo.hidden = true;
      if (self.lastSeed) self.seed(self.lastSeed);
    },
  };
  const edited = (e) => {
    if (e.target.classList.contains("variant")) return;  // another kind of target is no edit of the values
    self.edited = true;
    undo.hidden = false;
  };
  el.addEventListener("input", edited);
  el.addEventListener("change", edited);
  undo.addEventListener("click", () => self.reset());
  raw.addEventListener("click", () => {
    if (self.json()) {  // back to the fields, with what the text says
      let v;
      try { v = JSON.parse(area.value); } catch (err) {
        area.setCustomValidity(`not valid JSON: ${err.message}`);
        area.reportValidity();
        return;
      }
      area.setCustomValidity("");
      f.set(v);
    } else {
      let v;
      try { v = f.get(); } catch { v = undefined; }
      area.value = v === undefined ? "" : JSON.stringify(v, null, 1);
    }
    const json = !self.json();
    raw.setAttribute("aria-pressed", String(json));
    area.hidden = !json;
    f.el.hidden = json;
  });
  return self;
}

// --- read-outs --------------------------------------------------------------------------------------
// readout(schema, value) -> a Node: scalars as text, objects and short arrays as labelled fields (a position's x, y,
// z, a joint set's joints, each with its unit), anything large folded behind its size.
const SMALL = 16;

export function readout(schema = {}, value, depth = 0, key = "") {
  if (value === null || value === undefined) return $("span", { class: "v none", text: "–" });
  if (typeof value === "boolean") return document.createTextNode(String(value));
  if (typeof value !== "object") {
    return $("span", { class: "v", title: typeof value === "number" ? String(value) : null, text: fmt(value) });
  }
  if (Array.isArray(value)) {
    const scalars = value.every((x) => x === null || typeof x !== "object");
    if (scalars && value.length > 0 && value.length <= 8) {
      const items = schema.items && !Array.isArray(schema.items) ? schema.items : {};
      const labels = itemLabels(schema, value.length, key);
      const swatch = colour(schema, value, key);
      return $("span", { class: "fields" }, swatch,
        ...value.map((x, i) => entry(labels[i], String(i), items, x, depth)));
    }
    if (!value.length) return $("span", { class: "v none", text: "none" });
    return folded(value, `${value.length} item${value.length === 1 ? "" : "s"}`);
  }
  const keys = Object.keys(value);
  const flat = keys.every((k) => value[k] === null || typeof value[k] !== "object");
  if (keys.length > SMALL || (depth > 0 && (!flat || keys.length > 8)) || depth > 1) {
    return folded(value, `${keys.length} entries`);
  }
  const props = schema.properties || {};
  const extra = typeof schema.additionalProperties === "object" ? schema.additionalProperties : {};
  return $("span", { class: "fields" }, ...keys.map((k) => entry((props[k] || {}).title || k, k, props[k] || extra,
    value[k], depth)));
}

function entry(label, key, schema, value, depth) {
  const nested = value !== null && typeof value === "object";
  const unit = unitSymbol(schema);
  return $("span", { class: nested ? "f nested" : "f", "data-key": key },
    $("span", { class: "k", text: label }),
    $("span", { class: "fv" }, readout(schema, value, depth + 1, key)),
    unit && !nested ? $("span", { class: "u", title: unitName(schema), text: unit }) : null);
}

function colour(schema, value, key) {
  const text = `${key} ${schema.title || ""} ${schema.description || ""}`;
  if (value.length !== 3 || !/colou?r|\brgb\b/i.test(text) || !value.every((x) => typeof x === "number")) return null;
  const top = schema.items && schema.items.maximum !== undefined ? schema.items.maximum : Math.max(1, ...value) > 1 ? 255 : 1;
  const [r, g, b] = value.map((x) => Math.round(Math.min(1, Math.max(0, x / top)) * 255));
  return $("span", { class: "swatch", style: `background: rgb(${r} ${g} ${b})`, title: `rgb(${r}, ${g}, ${b})` });
}

function folded(value, summary) {
  const box = $("details", { class: "folded" }, $("summary", { text: summary }));
  const pre = $("pre", {});
  box.addEventListener("toggle", () => { if (box.open) pre.textContent = JSON.stringify(value, null, 1); });
  box.append(pre);
  return box;
}

// --- what the Thing's state says an input should start from ---------------------------------------------
// guesser(values, schemas)(schema) -> a value for `schema` from the Thing's current property values: an object input
// takes the keys it shares with an object property (a move's x, y, z from the current position; joints from the
// joint position), a scalar input the property its action or its key is named after (`panTo` and `panAngle` from
// `panPosition`), with the same unit.
const stemOf = (name) => name.replace(/^(set|go|move)(?=[A-Z])/, "").replace(/(To|Angle|Position|Value)$/, "")
  .toLowerCase();

export function guesser(values, schemas, action = "") {
  const records = Object.entries(values).map(([name, v]) => [name, asRecord(schemas[name] || {}, v, name)])
    .filter(([, r]) => r !== null);
  return (schema, key) => {
    const kind = kindOf(schema);
    if (kind === "object" && schema.properties) {
      const keys = Object.keys(schema.properties);
      let best = null, score = 0;
      for (const [name, r] of records) {
        const shared = keys.filter((k) => k in r).length;
        const better = shared > score || (shared === score && best && (schemas[name] || {}).readOnly
          && !(schemas[best] || {}).readOnly);
        if (shared >= Math.max(1, Math.ceil(keys.length / 2)) && better) { best = name; score = shared; }
      }
      if (!best) return undefined;
      const r = records.find(([n]) => n === best)[1];
      return Object.fromEntries(keys.filter((k) => k in r).map((k) => [k, r[k]]));
    }
    const stem = stemOf(key || action);
    if ((kind === "number" || kind === "integer" || kind === "boolean") && stem.length >= 3) {
      const hit = Object.entries(values).find(([name, v]) => name.toLowerCase().startsWith(stem)
        && typeof v === (kind === "boolean" ? "boolean" : "number") && unitName(schemas[name]) === unitName(schema));
      return hit ? hit[1] : undefined;
    }
    return undefined;
  };
}

function asRecord(schema, v, key) {
  if (v && typeof v === "object" && !Array.isArray(v)) return v;
  if (Array.isArray(v) && v.length <= 8) {
    const labels = itemLabels(schema, v.length, key);
    return /^\d/.test(labels[0]) ? null : Object.fromEntries(labels.map((l, i) => [l, v[i]]));
  }
  return null;
}
