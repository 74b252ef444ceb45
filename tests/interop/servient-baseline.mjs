#!/usr/bin/env node
// node-wot's own HTTP servient exposing a `light-left` equivalent to twinmesh's (devices/lights.py):
// the baseline of the HTTP benchmark and the server the interop harness is proven against.
// node-wot serves observations as long-poll only; a small middleware adds an SSE form (unnamed
// `data:` events, the kind node-wot's client delivers) to every observable property and event.
//
//   node servient-baseline.mjs [--port 8090] [--basic user:password] [--exit-with-stdin]
//
// Listens on 127.0.0.1 (--port 0 picks a free port) and prints one JSON line on stdout when ready:
// {"ready": true, "port": N, "things": {"light-left": "<TD URL>"}}. Exits on SIGTERM/SIGINT and,
// with --exit-with-stdin, when its stdin closes, so a parent that dies leaves nothing behind.

import { parseArgs } from "node:util";

console.log = console.info = console.debug = console.error; // stdout carries the ready line only

const { values: args } = parseArgs({
    options: {
        port: { type: "string", default: "8090" },
        basic: { type: "string" },
        "exit-with-stdin": { type: "boolean", default: false },
    },
});
const port = Number(args.port);
if (!Number.isInteger(port) || port < 0 || port > 65535) {
    console.error(`servient-baseline: bad --port ${args.port}`);
    process.exit(1);
}
delete process.env.WOT_PORT; // node-wot's HttpServer would let these override --port
delete process.env.PORT;

const { Servient } = await import("@node-wot/core");
const { HttpServer } = (await import("@node-wot/binding-http")).default;

const THING_ID = "urn:twinmesh:baseline:light-left";
const COLOR = { type: "array", items: { type: "number", minimum: 0, maximum: 1 }, minItems: 3, maxItems: 3 };

const basicAuthorization = args.basic !== undefined && `Basic ${Buffer.from(args.basic).toString("base64")}`;
let thing; // produced below, once the server knows its port

// GET /light-left/{properties|events}/{name}/sse: one `data: <json>` event per change.
async function sse(req, res, next) {
    const match = /^\/light-left\/(properties|events)\/([^/?]+)\/sse$/.exec(req.url);
    if (req.method !== "GET" || !match) return next();
    const [kind, name] = [match[1], decodeURIComponent(match[2])];
    const formIndex = (kind === "properties" ? thing.properties : thing.events)[name]?.forms
        .findIndex((form) => form.subprotocol === "sse");
    if (!(formIndex >= 0)) return next(); // node-wot answers 404
    if (basicAuthorization && req.headers.authorization !== basicAuthorization) {
        res.writeHead(401, { "WWW-Authenticate": 'Basic realm="light-left"' }).end();
        return;
    }
    const options = { formIndex };
    let sent = Promise.resolve(); // keeps events in order
    const listener = (content) => {
        sent = sent.then(async () => res.write(`data: ${(await content.toBuffer()).toString()}\n\n`));
    };
    // Subscribe before the headers go out: a client counts the subscription as open once it has them.
    if (kind === "properties") await thing.handleObserveProperty(name, listener, options);
    else await thing.handleSubscribeEvent(name, listener, options);
    req.on("close", () => {
        if (kind === "properties") thing.handleUnobserveProperty(name, listener, options);
        else thing.handleUnsubscribeEvent(name, listener, options);
    });
    res.writeHead(200, { "Content-Type": "text/event-stream", "Cache-Control": "no-cache" });
    res.write(": subscribed\n\n");
}

const server = new HttpServer({
    port,
    address: "127.0.0.1",
    middleware: (req, res, next) => sse(req, res, next).catch((e) => {
        console.error(`servient-baseline: SSE ${req.url}: ${e.message}`);
        if (!res.headersSent) res.writeHead(500);
        res.end();
    }),
    ...(args.basic !== undefined && { security: [{ scheme: "basic" }] }),
});
const servient = new Servient();
servient.addServer(server);
if (args.basic !== undefined) {
    const [username, ...rest] = args.basic.split(":");
    servient.addCredentials({ [THING_ID]: { username, password: rest.join(":") } });
}
const wot = await servient.start();
// Forms are written at expose time from baseUri: set it once the real port is known.
const base = `http://127.0.0.1:${server.getPort()}`;
server.baseUri = base;

thing = await wot.produce({
    title: "light-left",
    id: THING_ID,
    description: "node-wot baseline of twinmesh's light-left",
    ...(args.basic !== undefined && {
        securityDefinitions: { basic_sc: { scheme: "basic", in: "header" } },
        security: ["basic_sc"],
    }),
    properties: {
        lightState: { title: "Light state", type: "boolean", observable: true, readOnly: false, writeOnly: false },
        lightColor: { title: "Light colour", ...COLOR, observable: true, readOnly: false, writeOnly: false },
    },
    actions: {
        switchOn: { title: "Switch on", safe: false, idempotent: true, synchronous: true },
        switchOff: { title: "Switch off", safe: false, idempotent: true, synchronous: true },
        setColor: {
            title: "Set colour",
            safe: false,
            idempotent: true,
            synchronous: true,
            input: {
                type: "object",
                required: ["r", "g", "b"],
                properties: Object.fromEntries(["r", "g", "b"].map((c) => [c, { type: "number", minimum: 0, maximum: 1 }])),
            },
            output: { title: "The new colour", ...COLOR },
        },
    },
    events: {
        stateChanged: { title: "State changed", data: { type: "boolean" } },
    },
});

const state = { lightState: false, lightColor: [1, 1, 1] };

async function setState(on) {
    if (state.lightState === on) return;
    state.lightState = on;
    await thing.emitPropertyChange("lightState");
    thing.emitEvent("stateChanged", on);
}

async function setColor(color) {
    state.lightColor = color;
    await thing.emitPropertyChange("lightColor");
    return color;
}

// value() validates against the affordance's schema: invalid input throws (node-wot answers 500).
thing.setPropertyReadHandler("lightState", async () => state.lightState);
thing.setPropertyWriteHandler("lightState", async (input) => setState(await input.value()));
thing.setPropertyReadHandler("lightColor", async () => state.lightColor);
thing.setPropertyWriteHandler("lightColor", async (input) => setColor(await input.value()));
thing.setActionHandler("switchOn", async () => void (await setState(true)));
thing.setActionHandler("switchOff", async () => void (await setState(false)));
thing.setActionHandler("setColor", async (input) => {
    const { r, g, b } = await input.value();
    return setColor([r, g, b]);
});
await thing.expose();
const sseForm = (path, op) => ({ href: `${base}/light-left/${path}/sse`, contentType: "application/json", subprotocol: "sse", op });
for (const [name, property] of Object.entries(thing.properties)) {
    if (property.observable) property.forms.push(sseForm(`properties/${name}`, ["observeproperty", "unobserveproperty"]));
}
for (const [name, event] of Object.entries(thing.events)) {
    event.forms.push(sseForm(`events/${name}`, ["subscribeevent", "unsubscribeevent"]));
}

process.stdout.write(JSON.stringify({ ready: true, port: server.getPort(), things: { "light-left": `${base}/light-left` } }) + "\n");

// Parked long-poll requests would hold server.close() for an hour: exit without waiting for them.
const stop = () => process.exit(0);
process.on("SIGTERM", stop);
process.on("SIGINT", stop);
if (args["exit-with-stdin"]) process.stdin.on("close", stop).resume();
