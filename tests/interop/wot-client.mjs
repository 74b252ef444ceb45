#!/usr/bin/env node
// node-wot 0.9.2 as a scripted WoT consumer, driven by the Python interop tests (see npm.py).
//
//   node wot-client.mjs <TD URL> <script.json | -> [--basic user:password] [--bearer token]
//   node wot-client.mjs --many <scripts.json | -> [--basic user:password] [--bearer token]
//
// --many drives several Things from one servient (node-wot loads once), up to --parallel (default 8) at
// a time: the input is a JSON list of {"url": TD URL, "steps": [...]}, and every output line carries
// "thing": the index of its entry in that list, so one Thing's lines read as a single run's.
//
// The script is a JSON list of steps, run in order. stdout carries JSON lines only: first
// {"op":"consume", ...} for fetching and consuming the TD, then one line per step:
// {"i": <step index>, "op": ..., "ok": true, "value": ...} or {"i": ..., "ok": false, "error": ...}.
// Credentials are registered under the TD's `id`, the way node-wot looks them up.
// Exit codes: 0 all steps ran (their errors are results), 2 the TD could not be fetched or
// consumed (the consume line says why), 1 harness failure (message on stderr).
//
// Steps (every step may carry "timeoutMs", default 10000, and an "id" to refer to it):
//   {"op":"readProperty","name":P}                      -> value
//   {"op":"readProperty","name":P,"raw":true}           -> raw: the payload as text (node-wot's value() refuses
//                                                          a property whose TD gives no data schema type)
//   {"op":"readAllProperties"}                          -> value: {P: value, ...}
//   {"op":"writeProperty","name":P,"value":V}
//   {"op":"invokeAction","name":A,"input":V?}           -> value (absent when the action has no output)
//   {"op":"observeProperty","name":P,"count":1}         -> values: [...], after `count` notifications
//   {"op":"subscribeEvent","name":E,"count":1}          -> values: [...]
//     with "background": true the step reports {"started": true} as soon as the subscription is
//     open and collection goes on while later steps run; it unsubscribes once `count` arrived.
//   {"op":"await","ref":ID_OR_INDEX,"count":N?}         -> values: the background step's, so far;
//     waits for N notifications (default: the step's count).
// readProperty, writeProperty, invokeAction, observeProperty and subscribeEvent take "formIndex"
// (use that form of the affordance, e.g. the SSE one) and "uriVariables".

import { readFileSync } from "node:fs";
import { parseArgs } from "node:util";

// stdout is for result lines only; node-wot and its dependencies log through console.
console.log = console.info = console.debug = console.error;

const OPS = new Set([
    "readProperty", "readAllProperties", "writeProperty", "invokeAction",
    "observeProperty", "subscribeEvent", "await",
]);
const NAMED = new Set(["readProperty", "writeProperty", "invokeAction", "observeProperty", "subscribeEvent"]);
const DEFAULT_TIMEOUT_MS = 10000;

class HarnessError extends Error {}
class TimeoutError extends Error {}

function emit(line) {
    process.stdout.write(JSON.stringify(line) + "\n");
}

function errorResult(e) {
    const result = { ok: false, error: e instanceof Error ? e.message : String(e) };
    if (e instanceof TimeoutError) result.timeout = true;
    if (e instanceof Error && e.value !== undefined) result.invalidValue = e.value; // DataSchemaError
    return result;
}

// Rejects with TimeoutError when `promise` has not settled within `ms`.
async function within(ms, promise, what) {
    let timer;
    const timeout = new Promise((_, reject) => {
        timer = setTimeout(() => reject(new TimeoutError(`timeout: ${what} after ${ms} ms`)), ms);
    });
    try {
        return await Promise.race([promise, timeout]);
    } finally {
        clearTimeout(timer);
    }
}

function parseCli() {
    const { values, positionals } = parseArgs({
        allowPositionals: true,
        options: {
            basic: { type: "string" }, bearer: { type: "string" }, many: { type: "boolean" },
            parallel: { type: "string", default: "8" },
        },
    });
    if (positionals.length !== (values.many ? 1 : 2)) {
        throw new HarnessError("usage: node wot-client.mjs <TD URL> <script.json | -> | --many <scripts.json | -> "
            + "[--parallel N] [--basic user:password] [--bearer token]");
    }
    const [tdUrl, scriptPath] = values.many ? [null, positionals[0]] : positionals;
    let credentials;
    if (values.basic !== undefined) {
        const colon = values.basic.indexOf(":");
        if (colon < 0) throw new HarnessError("--basic wants user:password");
        credentials = { username: values.basic.slice(0, colon), password: values.basic.slice(colon + 1) };
    } else if (values.bearer !== undefined) {
        credentials = { token: values.bearer };
    }
    let script;
    try {
        script = JSON.parse(readFileSync(scriptPath === "-" ? 0 : scriptPath, "utf8"));
    } catch (e) {
        throw new HarnessError(`cannot read the script ${scriptPath}: ${e.message}`);
    }
    const things = values.many ? script : [{ url: tdUrl, steps: script }];
    if (!Array.isArray(things)) throw new HarnessError("--many wants a JSON list of {url, steps}");
    for (const thing of things) {
        if (thing === null || typeof thing.url !== "string") throw new HarnessError("each entry of --many needs a url");
        checkSteps(thing.steps);
    }
    const parallel = Number.parseInt(values.parallel, 10);
    if (!(parallel >= 1)) throw new HarnessError("--parallel wants a whole number of at least 1");
    return { many: Boolean(values.many), credentials, things, parallel };
}

function checkSteps(steps) {
    if (!Array.isArray(steps)) throw new HarnessError("the script must be a JSON list of steps");
    const ids = new Map();
    steps.forEach((step, i) => {
        const where = `step ${i} (${JSON.stringify(step)})`;
        if (step === null || typeof step !== "object" || !OPS.has(step.op)) {
            throw new HarnessError(`${where}: op must be one of ${[...OPS].join(", ")}`);
        }
        if (NAMED.has(step.op) && typeof step.name !== "string") throw new HarnessError(`${where}: needs a name`);
        if (step.op === "writeProperty" && !("value" in step)) throw new HarnessError(`${where}: needs a value`);
        if (step.background && !["observeProperty", "subscribeEvent"].includes(step.op)) {
            throw new HarnessError(`${where}: only observeProperty and subscribeEvent run in the background`);
        }
        if (step.op === "await") {
            const target = typeof step.ref === "number" ? step.ref : ids.get(step.ref);
            if (target === undefined || target >= i || !steps[target].background) {
                throw new HarnessError(`${where}: ref must name an earlier background step (by id or index)`);
            }
            if (step.count > (steps[target].count ?? 1)) {
                throw new HarnessError(`${where}: count is more than the background step collects`);
            }
            step.target = target;
        }
        if (step.id !== undefined) ids.set(step.id, i);
    });
}

// The notifications of one observeProperty/subscribeEvent step, in arrival order.
class Notifications {
    constructor(count) {
        this.count = count;
        this.values = [];
        this.errors = [];
        this.closed = false;
        this.chain = Promise.resolve(); // decodes outputs one after the other, keeping their order
        this.signal = deferred();
    }

    // Listener for node-wot: every output is decoded and validated by node-wot's value(). Values
    // past `count` (in flight while unsubscribing) are dropped so that results are deterministic.
    receive(output) {
        this.chain = this.chain
            .then(() => output.value())
            .then(
                (value) => {
                    if (this.values.length < this.count) this.values.push(value);
                },
                (e) => this.errors.push(errorResult(e).error),
            )
            .then(() => this.changed());
    }

    fail(e) {
        if (this.closed) return; // node-wot reports its own abort when we unsubscribe
        this.errors.push(errorResult(e).error);
        this.changed();
    }

    changed() {
        const { resolve } = this.signal;
        this.signal = deferred();
        resolve();
    }

    // Resolves once `count` values or an error arrived; TimeoutError after `ms`.
    async waitFor(count, ms, what) {
        const arrived = async () => {
            while (this.values.length < count && this.errors.length === 0) await this.signal.promise;
        };
        try {
            await within(ms, arrived(), what);
        } catch (e) {
            if (!(e instanceof TimeoutError)) throw e;
            throw new TimeoutError(`timeout: ${this.values.length} of ${count} notifications of ${what} after ${ms} ms`);
        }
    }

    result(e) {
        const result = e ? errorResult(e) : { ok: this.errors.length === 0 };
        if (this.errors.length) Object.assign(result, { ok: false, error: this.errors.join("; ") });
        return { ...result, values: this.values };
    }
}

function deferred() {
    let resolve;
    const promise = new Promise((r) => (resolve = r));
    return { promise, resolve };
}

class Runner {
    constructor(wot, td) {
        this.wot = wot;
        this.td = td;
        this.thing = null;
        this.subscriptions = new Map(); // step index -> { notifications, subscription }
    }

    async consume() {
        this.thing = await this.wot.consume(this.td);
    }

    async run(step, i) {
        const ms = step.timeoutMs ?? DEFAULT_TIMEOUT_MS;
        const options = {};
        if (step.formIndex !== undefined) options.formIndex = step.formIndex;
        if (step.uriVariables !== undefined) options.uriVariables = step.uriVariables;
        const what = `${step.op} ${step.name ?? ""}`.trim();
        // node-wot 0.9.2 sends no credentials for a formIndex request on a ConsumedThing that has
        // made a request before: such steps get a ConsumedThing of their own.
        const t = step.formIndex === undefined ? this.thing : await this.wot.consume(this.td);
        switch (step.op) {
            case "readProperty": {
                const output = await within(ms, t.readProperty(step.name, options), what);
                if (step.raw) return { ok: true, raw: Buffer.from(await output.arrayBuffer()).toString() };
                return { ok: true, value: await within(ms, output.value(), what) };
            }
            case "readAllProperties": {
                const outputs = await within(ms, t.readAllProperties(), what);
                const value = {};
                for (const [name, output] of outputs) value[name] = await within(ms, output.value(), `${what} ${name}`);
                return { ok: true, value };
            }
            case "writeProperty":
                await within(ms, t.writeProperty(step.name, step.value, options), what);
                return { ok: true };
            case "invokeAction": {
                const output = await within(ms, t.invokeAction(step.name, step.input, options), what);
                if (t.actions[step.name]?.output === undefined) return { ok: true }; // node-wot has no value then
                return { ok: true, value: await within(ms, output.value(), what) };
            }
            case "observeProperty":
            case "subscribeEvent":
                return this.subscribe(step, i, ms, options, what);
            case "await": {
                const { notifications } = this.subscriptions.get(step.target);
                try {
                    await notifications.waitFor(step.count ?? notifications.count, ms, `await ${step.ref}`);
                } catch (e) {
                    return notifications.result(e);
                }
                return notifications.result();
            }
        }
    }

    async subscribe(step, i, ms, options, what) {
        const count = step.count ?? 1;
        const notifications = new Notifications(count);
        // node-wot lets a ConsumedThing observe a property only once: one ConsumedThing per subscription.
        const thing = await this.wot.consume(this.td);
        const method = step.op === "observeProperty" ? "observeProperty" : "subscribeEvent";
        const entry = { notifications, subscription: null };
        const listener = (output) => {
            notifications.receive(output);
            notifications.chain.then(() => {
                if (notifications.values.length >= count && entry.subscription) this.stop(entry);
            });
        };
        entry.subscription = await within(
            ms, thing[method](step.name, listener, (e) => notifications.fail(e), options), `${what}: subscribing`);
        this.subscriptions.set(i, entry);
        if (step.background) return { ok: true, started: true };
        try {
            await notifications.waitFor(count, ms, what);
        } catch (e) {
            return notifications.result(e);
        } finally {
            await this.stop(entry);
        }
        return notifications.result();
    }

    async stop(entry) {
        if (entry.notifications.closed) return;
        entry.notifications.closed = true;
        try {
            await entry.subscription.stop();
        } catch (e) {
            console.error(`wot-client: unsubscribing failed: ${e.message}`);
        }
    }

    async close() {
        for (const entry of this.subscriptions.values()) await this.stop(entry);
    }
}

// One Thing: consume its TD, run its steps in order; `say` writes its lines. 0, or 2 if it could not be consumed.
async function drive(wot, servient, credentials, tdUrl, steps, say) {
    let runner;
    try {
        const td = tdUrl.startsWith("file:")  // a TD written to disk (twinmesh tdgen), as a file:// URL
            ? JSON.parse(readFileSync(new URL(tdUrl), "utf8"))
            : await within(DEFAULT_TIMEOUT_MS, wot.requestThingDescription(tdUrl), `fetching ${tdUrl}`);
        if (credentials) servient.addCredentials({ [td.id]: credentials });
        runner = new Runner(wot, td);
        await runner.consume();
        say({ op: "consume", ok: true, id: td.id, title: td.title });
    } catch (e) {
        say({ op: "consume", ...errorResult(e) });
        return 2;
    }

    for (const [i, step] of steps.entries()) {
        let result;
        try {
            result = await runner.run(step, i);
        } catch (e) {
            result = errorResult(e);
        }
        say({ i, op: step.op, ...(step.id !== undefined && { id: step.id }), ...result });
    }
    await runner.close();
    return 0;
}

async function main() {
    const { many, credentials, things, parallel } = parseCli();
    const { Servient } = await import("@node-wot/core");
    const { HttpClientFactory } = (await import("@node-wot/binding-http")).default;
    const servient = new Servient();
    servient.addClientFactory(new HttpClientFactory());
    const wot = await servient.start();

    let code = 0;
    if (!many) {
        code = await drive(wot, servient, credentials, things[0].url, things[0].steps, emit);
    } else {
        let next = 0;
        const worker = async () => {
            while (next < things.length) {
                const k = next++;
                await drive(wot, servient, credentials, things[k].url, things[k].steps,
                    (line) => emit({ thing: k, ...line }));
            }
        };
        await Promise.all(Array.from({ length: Math.min(parallel, things.length) }, worker));
    }
    await servient.shutdown();
    return code;
}

process.on("unhandledRejection", (e) => console.error("wot-client: unhandled rejection:", e));

main().then(
    (code) => process.exit(code), // open long-poll requests would keep the event loop alive
    (e) => {
        console.error(e instanceof HarnessError ? `wot-client: ${e.message}` : e);
        process.exit(1);
    },
);
