#!/usr/bin/env node
// The lab's cube workflow (SPEC §3) as a student would write it with node-wot 0.9.2: WoT HTTP
// Things consumed from their TDs, driven by affordance name only, no sleeps.
//
//   node cube-workflow.mjs <base URL> [--runs N] [--timeout-ms MS]
//
// The TD of each device is fetched from <base URL>/<thing> (the twinmesh adapter's layout). Before
// a belt starts, the script subscribes to the infrared sensor's `detectedObject` (over the SSE
// form: node-wot counts that subscription as open once the stream's headers arrived, so no event
// can slip by), then reads `objectPresence` (the cube may already be there), then starts the belt
// and stops it at the first `true`. Each wait is bounded by --timeout-ms (a failure, not a sleep).
//
// stdout carries JSON lines only: one {"run", "step", "title", "ms", ...} per step, then per run
// {"run", "done": true, "color": [r, g, b], "events": {"infrared-sensor-2": [...], ...}, "ms"};
// on failure {"run", "step", "title", "error"} and exit code 1.

import { parseArgs } from "node:util";

console.log = console.info = console.debug = console.error; // stdout is for result lines

const { values: args, positionals } = parseArgs({
    allowPositionals: true,
    options: { runs: { type: "string", default: "1" }, "timeout-ms": { type: "string", default: "120000" } },
});
if (positionals.length !== 1) {
    console.error("usage: node cube-workflow.mjs <base URL> [--runs N] [--timeout-ms MS]");
    process.exit(2);
}
const base = positionals[0].replace(/\/$/, "");
const runs = Number(args.runs);
const timeoutMs = Number(args["timeout-ms"]);
const DEVICES = ["dobot", "conveyor-belt-1", "conveyor-belt-2", "infrared-sensor-1", "infrared-sensor-2",
    "color-sensor", "uarm"];

function emit(line) {
    process.stdout.write(JSON.stringify(line) + "\n");
}

function within(ms, promise, what) {
    let timer;
    const timeout = new Promise((_, reject) => {
        timer = setTimeout(() => reject(new Error(`${what}: nothing within ${ms} ms`)), ms);
    });
    return Promise.race([promise, timeout]).finally(() => clearTimeout(timer));
}

const { Servient } = await import("@node-wot/core");
const { HttpClientFactory } = (await import("@node-wot/binding-http")).default;
const servient = new Servient();
servient.addClientFactory(new HttpClientFactory());
const wot = await servient.start();

const tds = {};
const things = {};
for (const name of DEVICES) {
    tds[name] = await wot.requestThingDescription(`${base}/${name}`);
    things[name] = await wot.consume(tds[name]);
}

const invoke = (thing, action, input) => things[thing].invokeAction(action, input);
const read = async (thing, prop) => (await things[thing].readProperty(prop)).value();
const goTo = (x, y, z) => invoke("uarm", "goTo", { x, y, z });
const seen = {}; // sensor -> every detectedObject value received

// Subscribe to the sensor's detectedObject, check the presence, run the belt until the cube is seen.
async function beltUntilSeen(belt, start, sensor) {
    // a ConsumedThing of its own per subscription (node-wot subscribes a ConsumedThing once per event)
    const thing = await wot.consume(tds[sensor]);
    const formIndex = tds[sensor].events.detectedObject.forms.findIndex((f) => f.subprotocol === "sse");
    let arrived;
    const present = new Promise((resolve, reject) => (arrived = { resolve, reject }));
    seen[sensor] ??= [];
    const subscription = await thing.subscribeEvent(
        "detectedObject",
        async (output) => {
            const value = await output.value();
            seen[sensor].push(value);
            if (value === true) arrived.resolve();
        },
        (e) => arrived.reject(e),
        formIndex >= 0 ? { formIndex } : undefined,
    );
    try {
        if ((await read(sensor, "objectPresence")) === true) return "already there";
        await invoke(belt, start);
        await within(timeoutMs, present, `${sensor} detectedObject`);
        return "";
    } finally {
        await invoke(belt, "stopBelt");
        await subscription.stop();
    }
}

async function cubeWorkflow(run) {
    let color;
    const steps = [
        ["dobot getCube", () => invoke("dobot", "getCube")],
        ["conveyor-belt-2 forward until infrared-sensor-2", () =>
            beltUntilSeen("conveyor-belt-2", "startBeltForward", "infrared-sensor-2")],
        ["uarm picks the cube up", async () => {
            await invoke("uarm", "gripOpen");
            await goTo(192, 192, 87);
            await goTo(192, 192, 52);
            await invoke("uarm", "gripClose");
            await goTo(192, 192, 87);
        }],
        ["uarm over the colour sensor", () => goTo(180, 0, 60)],
        ["colour sensor reads", async () => (color = await read("color-sensor", "color"))],
        ["uarm puts the cube on conveyor-belt-1", async () => {
            await goTo(200, -200, 90);
            await goTo(200, -200, 70);
            await invoke("uarm", "gripOpen");
            await goTo(200, -200, 90);
        }],
        ["conveyor-belt-1 backward until infrared-sensor-1", () =>
            beltUntilSeen("conveyor-belt-1", "startBeltBackward", "infrared-sensor-1")],
        ["dobot returnCube", () => invoke("dobot", "returnCube")],
    ];
    const started = Date.now();
    for (const [i, [title, body]] of steps.entries()) {
        const t0 = Date.now();
        try {
            await body();
        } catch (e) {
            emit({ run, step: i + 1, title, error: e instanceof Error ? e.message : String(e) });
            return false;
        }
        emit({ run, step: i + 1, title, ms: Date.now() - t0, ...(i === 4 && { color }) });
    }
    emit({ run, done: true, color, events: seen, ms: Date.now() - started });
    return true;
}

let ok = true;
for (let run = 1; run <= runs && ok; run++) {
    for (const key of Object.keys(seen)) delete seen[key];
    ok = await cubeWorkflow(run);
}
await servient.shutdown();
process.exit(ok ? 0 : 1); // an open event stream would keep the event loop alive
