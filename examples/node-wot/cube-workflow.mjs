#!/usr/bin/env node
// The lab's cube workflow with node-wot, by affordance names only: the script a student writes for the
// real IoT platform, run against the twin's HTTP adapter. No sleeps: every action answers when its
// motion is over, and a belt runs until its infrared sensor's `detectedObject` event says the cube is there.
//
//   npm install                                  # node-wot 0.9.2, once, in this folder
//   node cube-workflow.mjs [ADAPTER_URL]         # default http://127.0.0.1:8080 (`twinmesh up iot-platform`)
//
// Prints each step as it ends and the colour the sensor read; exits 1 on the first failed step.

import { Servient } from "@node-wot/core";
import httpBinding from "@node-wot/binding-http"; // a CommonJS package: its names come with the default export

const { HttpClientFactory } = httpBinding;

const base = (process.argv[2] ?? "http://127.0.0.1:8080").replace(/\/$/, "");
const WAIT_MS = 120000; // how long a belt may run before the sensor must have seen the cube

const servient = new Servient();
servient.addClientFactory(new HttpClientFactory());
const WoT = await servient.start();

const tds = {};
const things = {};
for (const name of ["dobot", "conveyor-belt-1", "conveyor-belt-2", "infrared-sensor-1", "infrared-sensor-2",
    "color-sensor", "uarm"]) {
    tds[name] = await WoT.requestThingDescription(`${base}/${name}`);
    things[name] = await WoT.consume(tds[name]);
}
const invoke = (thing, action, input) => things[thing].invokeAction(action, input);
const read = async (thing, property) => (await things[thing].readProperty(property)).value();
const goTo = (x, y, z) => invoke("uarm", "goTo", { x, y, z }); // the real uArm's frame, mm

// Run a belt until its sensor sees the cube: subscribe first, then look (it may be there already), then start.
async function beltUntilSeen(belt, start, sensor) {
    const watcher = await WoT.consume(tds[sensor]); // a subscription of its own
    let seen;
    const arrived = new Promise((resolve, reject) => {
        seen = resolve;
        setTimeout(() => reject(new Error(`${sensor} saw nothing within ${WAIT_MS} ms`)), WAIT_MS).unref();
    });
    const sse = tds[sensor].events.detectedObject.forms.findIndex((form) => form.subprotocol === "sse");
    const subscription = await watcher.subscribeEvent("detectedObject", async (data) => {
        if ((await data.value()) === true) seen();
    }, undefined, sse >= 0 ? { formIndex: sse } : undefined);
    try {
        if ((await read(sensor, "objectPresence")) !== true) {
            await invoke(belt, start);
            await arrived;
        }
    } finally {
        await invoke(belt, "stopBelt");
        await subscription.stop();
    }
}

let color;
const steps = [
    ["dobot takes a cube to conveyor belt 2", () => invoke("dobot", "getCube")],
    ["belt 2 runs until infrared sensor 2 sees it", () =>
        beltUntilSeen("conveyor-belt-2", "startBeltForward", "infrared-sensor-2")],
    ["uarm picks it up", async () => {
        await invoke("uarm", "gripOpen");
        await goTo(192, 192, 87);
        await goTo(192, 192, 52);
        await invoke("uarm", "gripClose");
        await goTo(192, 192, 87);
    }],
    ["uarm holds it over the colour sensor", () => goTo(180, 0, 60)],
    ["the colour sensor reads it", async () => { color = await read("color-sensor", "color"); }],
    ["uarm puts it on conveyor belt 1", async () => {
        await goTo(200, -200, 90);
        await goTo(200, -200, 70);
        await invoke("uarm", "gripOpen");
        await goTo(200, -200, 90);
    }],
    ["belt 1 runs back until infrared sensor 1 sees it", () =>
        beltUntilSeen("conveyor-belt-1", "startBeltBackward", "infrared-sensor-1")],
    ["dobot returns it to the warehouse", () => invoke("dobot", "returnCube")],
];

let failed = false;
for (const [i, [title, run]] of steps.entries()) {
    try {
        await run();
        console.log(`${i + 1}. ${title}: done`);
    } catch (error) {
        console.log(`${i + 1}. ${title}: FAILED: ${error instanceof Error ? error.message : error}`);
        failed = true;
        break;
    }
}
if (!failed) console.log(`colour: ${JSON.stringify(color)}`);
await servient.shutdown();
process.exit(failed ? 1 : 0); // an event stream left open would keep node running
