#!/usr/bin/env node
// The Eclipse Thingweb TD Playground (validator and assertion tester) on TDs and TMs, offline.
//
//   node td-playground.cjs <contexts dir> < documents.json
//
// stdin: a JSON list of {"name": ..., "kind": "td" | "tm", "document": {...}}. stdout: one JSON line
// per document: {"name", "report": {json, schema, defaults, jsonld, additional}, "details": {...},
// "failed": [assertion ids that failed], "counts": {pass, fail, not-impl, null}, "log": [...]}.
// JSON-LD expansion runs with a document loader that serves the TD 1.0, TD 1.1 and Discovery
// contexts from local copies (tests/data/wot/contexts) and refuses any other URL: no network.
"use strict";
const fs = require("fs");
const path = require("path");
const jsonld = require("jsonld");  // the instance the Playground core uses (hoisted by npm)
const core = require("@thing-description-playground/core");

// The assertion checks make a new Ajv and compile each of their ~300 assertion schemas for every document
// (`util.validate`), which is nearly all of the Playground's time. The same schema, compiled once with the same
// options, validates the same way: compile each schema once per process and keep its Ajv. Patched before the
// assertions module loads, as its checks take `validate` from `util` when they load.
const util = require("@thing-description-playground/assertions/util");
const compiled = new Map();  // a schema's JSON -> the Ajv it was compiled into
const validateOnce = util.validate;
util.validate = (jsonData, schema, logFunc) => {
    const key = JSON.stringify(schema);
    let ajv = compiled.get(key);
    if (ajv === undefined) {
        ajv = validateOnce({}, schema, logFunc).ajvObject;  // the Playground's own Ajv, options and formats
        compiled.set(key, ajv);
    }
    return { valid: ajv.validate("assertion", jsonData), ajvObject: ajv };
};
const assertions = require("@thing-description-playground/assertions");

const CONTEXTS = {
    "https://www.w3.org/2019/wot/td/v1": "td-v1.jsonld",
    "https://www.w3.org/2022/wot/td/v1.1": "td-v1.1.jsonld",
    "https://www.w3.org/2022/wot/discovery": "discovery.jsonld",
};

function offlineLoader(dir) {
    return async (url) => {
        const file = CONTEXTS[url];
        if (!file) throw new Error(`no local copy of ${url} (the tests run offline)`);
        return { contextUrl: null, documentUrl: url, document: JSON.parse(fs.readFileSync(path.join(dir, file), "utf8")) };
    };
}

// the assertion tester looks for the core's schemas under its own node_modules; npm hoists them
const CORE_DIR = path.dirname(require.resolve("@thing-description-playground/core/package.json"));
const NESTED = path.join("node_modules", "@thing-description-playground", "core") + path.sep;
function fileLoad(location) {
    const i = location.indexOf(NESTED);
    const file = i >= 0 ? path.join(CORE_DIR, location.slice(i + NESTED.length)) : location;
    return fs.promises.readFile(file, "utf8");
}

async function check({ name, kind, document }) {
    const text = JSON.stringify(document);
    const log = [];
    const validate = kind === "tm" ? core.tmValidator : core.tdValidator;
    const { report, details } = await validate(text, (line) => log.push(String(line)), {});
    const assert = kind === "tm" ? assertions.tmAssertions : assertions.tdAssertions;
    const results = await assert([text], fileLoad, () => {});
    const counts = {};
    for (const r of results) counts[r.Status] = (counts[r.Status] || 0) + 1;
    const failed = results.filter((r) => r.Status === "fail").map((r) => r.ID);
    return { name, report, details, failed, counts, log };
}

async function main() {
    const [dir] = process.argv.slice(2);
    if (!dir) throw new Error("usage: td-playground.cjs <contexts dir> < documents.json");
    jsonld.documentLoader = offlineLoader(dir);
    const documents = JSON.parse(fs.readFileSync(0, "utf8"));
    for (const d of documents) process.stdout.write(JSON.stringify(await check(d)) + "\n");
}

main().catch((e) => { process.stderr.write(`${e.stack || e}\n`); process.exit(1); });
