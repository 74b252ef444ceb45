#!/usr/bin/env node
// A mock of the real lab for the bridge and guard tests: node-wot servients exposing the real lab's
// TDs (tests/data/reference-tds/real-lab: titles, affordances and schemas as they are), behind basic
// authentication, with minimal behaviour and a log of every request received.
//
//   node real-lab.mjs --tds DIR [--tds DIR2 ...] [--port 0] [--basic user:password] [--tls-key K --tls-cert C] [--exit-with-stdin]
//
// Each TD is served at GET /td/<file name without .json> as the real lab wrote it, its https hosts
// replaced by this server (paths kept: the uArm's goTo stays at .../uarm/actions/goto; MQTT forms
// kept, for a client to ignore). Requests on those real paths are routed to the node-wot Thing
// exposed for the TD (node-wot's own paths are named after the title), so a client must follow the
// forms, not the affordance names. Behaviour: the uArm's `location` follows goTo, go, goHome and the
// turns; a belt remembers `speed` and whether it runs; writing an infrared sensor's `objectPresence`
// fires `detectedObject` (long-poll, node-wot's own); the Dobot's actions only log.
//
// GET /_log: every request received ({seq, method, path, authorized}) and every handler call
// ({seq, thing, affordance, input}); DELETE /_log empties it. Neither needs credentials.
// Prints {"ready": true, "port": N, "things": {"Uarm": "<TD URL>", ...}} on stdout when ready.

import { readFileSync, readdirSync } from "node:fs";
import { join } from "node:path";
import { parseArgs } from "node:util";

console.log = console.info = console.debug = console.error; // stdout carries the ready line only

const { values: args } = parseArgs({
    options: {
        tds: { type: "string", multiple: true },
        port: { type: "string", default: "0" },
        basic: { type: "string" },
        "tls-key": { type: "string" },
        "tls-cert": { type: "string" },
        "exit-with-stdin": { type: "boolean", default: false },
    },
});
delete process.env.WOT_PORT;
delete process.env.PORT;

const { Servient } = await import("@node-wot/core");
const { HttpServer } = (await import("@node-wot/binding-http")).default;

const log = [];
let seq = 0;
const note = (entry) => log.push({ seq: ++seq, ...entry });
const expected = args.basic !== undefined && `Basic ${Buffer.from(args.basic).toString("base64")}`;

const documents = Object.fromEntries([].concat(args.tds).flatMap((dir) => readdirSync(dir)
    .filter((f) => f.endsWith(".json")).map((f) => [f.slice(0, -5), JSON.parse(readFileSync(join(dir, f), "utf8"))])));
const routes = new Map(); // "METHOD real-path" or "real-path" -> node-wot path
let base = "";

function served(name) {
    const text = JSON.stringify(documents[name]).replace(/https:\/\/(129\.187\.45\.8|remotelab\.esi\.cit\.tum\.de):8081/g, base);
    return text;
}

async function middleware(req, res, next) {
    const url = new URL(req.url, base);
    if (url.pathname === "/_log") {
        if (req.method === "DELETE") log.length = 0;
        res.writeHead(200, { "Content-Type": "application/json" }).end(JSON.stringify(log));
        return;
    }
    const authorized = !expected || req.headers.authorization === expected;
    note({ method: req.method, path: url.pathname, authorized });
    if (!authorized) {
        res.writeHead(401, { "WWW-Authenticate": 'Basic realm="real-lab"' }).end();
        return;
    }
    const td = /^\/td\/([^/]+)$/.exec(url.pathname);
    if (td && documents[td[1]] && req.method === "GET") {
        res.writeHead(200, { "Content-Type": "application/td+json" }).end(served(td[1]));
        return;
    }
    const target = routes.get(url.pathname);
    if (target) req.url = target + url.search;
    next();
}

const tls = args["tls-key"] ? { serverKey: args["tls-key"], serverCert: args["tls-cert"] } : {};
const server = new HttpServer({ port: Number(args.port), address: "127.0.0.1", middleware, ...tls });
const servient = new Servient();
servient.addServer(server);
const wot = await servient.start();
base = `${args["tls-key"] ? "https" : "http"}://127.0.0.1:${server.getPort()}`;
server.baseUri = base;

const clean = (affordances) => Object.fromEntries(Object.entries(affordances ?? {})
    .map(([name, a]) => { const { forms, ...rest } = a; return [name, rest]; }));

const behaviours = {
    Uarm(thing) {
        const state = { location: { x: 150, y: 0, z: 100 }, homeLoc: { x: 150, y: 0, z: 100 } };
        thing.setPropertyReadHandler("location", async () => state.location);
        thing.setPropertyReadHandler("homeLoc", async () => state.homeLoc);
        thing.setPropertyWriteHandler("homeLoc", async (v) => { state.homeLoc = await v.value(); });
        const move = (p) => { state.location = { x: p.x, y: p.y, z: p.z }; };
        return {
            goTo: (v) => move(v), go: (v) => move(v), goHome: () => move(state.homeLoc),
            turnLeft: () => { state.location.y += 10; return { y: state.location.y }; },
            turnRight: () => { state.location.y -= 10; },
        };
    },
    WarehouseDobot(thing) {
        thing.setPropertyReadHandler("position", async () => ({ l: 450, x: 200, y: 0, z: 50, r: 0 }));
        return {};
    },
    ConveyorBelt(thing, td) {
        const state = { speed: 50, running: "stopped" };
        thing.setPropertyReadHandler("speed", async () => state.speed);
        thing.setPropertyWriteHandler("speed", async (v) => { state.speed = await v.value(); });
        const said = (action, running) => () => { state.running = running; return td.actions[action].output.const; };
        return {
            startBeltForward: said("startBeltForward", "forward"),
            startBeltBackward: said("startBeltBackward", "backward"),
            stopBelt: said("stopBelt", "stopped"),
        };
    },
    InfraredSensor(thing) {
        let present = false;
        thing.setPropertyReadHandler("objectPresence", async () => present);
        thing.setPropertyWriteHandler("objectPresence", async (v) => {
            present = await v.value();
            note({ thing: thing.title, affordance: "objectPresence", input: present });
            await thing.emitPropertyChange("objectPresence");
            thing.emitEvent("detectedObject", present);
        });
        return {};
    },
    UR10(thing) {
        const joints = { shoulder_pan_joint: 0, shoulder_lift_joint: -90, elbow_joint: 0, wrist_1_joint: -90,
            wrist_2_joint: 0, wrist_3_joint: 0 };
        let position = { x: 0, y: 0, z: 0 };
        thing.setPropertyReadHandler("getJointposition", async () => joints);
        thing.setPropertyReadHandler("getCartesianposition", async () => position);
        return {
            moveToJointPosition: (v) => { Object.assign(joints, v); },
            moveToCartesianPosition: (v) => { position = v; },
        };
    },
    ColorSensor(thing) {
        thing.setPropertyReadHandler("color", async () => [200, 30, 30]);
        thing.setPropertyReadHandler("lux", async () => 1200);
        thing.setPropertyReadHandler("temperature", async () => 4500);
        return {};
    },
};

const things = {};
for (const [name, td] of Object.entries(documents)) {
    const { forms, security, securityDefinitions, "@type": type, ...rest } = td;
    const thing = await wot.produce({
        ...rest,
        properties: clean(td.properties),
        actions: clean(td.actions),
        events: clean(td.events),
    });
    const kind = name.replace(/\d+$/, "");
    const actions = (behaviours[name] ?? behaviours[kind] ?? (() => ({})))(thing, td);
    for (const action of Object.keys(td.actions ?? {})) {
        thing.setActionHandler(action, async (input) => {
            const value = td.actions[action].input === undefined ? undefined : await input.value();
            note({ thing: td.title, affordance: action, input: value ?? null });
            const out = actions[action]?.(value);
            return out === undefined ? undefined : out;
        });
    }
    await thing.expose();
    const exposed = thing.getThingDescription();
    for (const kind of ["properties", "actions", "events"]) {
        for (const [affordance, a] of Object.entries(td[kind] ?? {})) {
            const own = exposed[kind][affordance].forms;
            for (const form of a.forms ?? []) {
                if (!/^https:/.test(form.href)) continue;
                const real = new URL(form.href).pathname;
                const ops = [].concat(form.op ?? []);
                const match = own.find((f) => ops.some((op) => [].concat(f.op ?? []).includes(op))
                    && (f.subprotocol ?? null) === (form.subprotocol ?? null)) ?? own[0];
                routes.set(real, new URL(match.href).pathname);
            }
        }
    }
    things[name] = `${base}/td/${name}`;
}

process.stdout.write(JSON.stringify({ ready: true, port: server.getPort(), things }) + "\n");

const stop = () => process.exit(0);
process.on("SIGTERM", stop);
process.on("SIGINT", stop);
if (args["exit-with-stdin"]) process.stdin.on("close", stop).resume();
