// ics35 configurator: pages over the JSON API and one WebSocket. Our own code, no framework.
"use strict";

const $ = (sel) => document.querySelector(sel);
const state = { status: null, servos: [], eeprom: null, plan: null, restore: null, traffic: [], trafficPaused: false,
  history: [], livePaused: false, updates: [], limits: null, liveParts: {}, liveIds: new Set(), sayingLost: false,
  motionAsked: 0, servoMotionAsked: 0, motionSeen: 0 };

// ---------------------------------------------------------------- talking to the server

function say(text, kind = "error", action = null) {
  state.sayingLost = false;  // set by api() when this is the words of a lost port
  state.backThen = null;  // what to do once the line is back, when not "try again" (set after api() said the loss)
  state.sayingStillLost = false;  // set when this is an early Reconnect's refusal (see reopenRobot)
  const box = $("#message");
  box.textContent = text;
  if (action) box.append(" ", el("button", { type: "button", onclick: () => { say(""); Promise.resolve(action.run()).catch(() => {}); } }, action.label));
  box.className = kind;
  box.hidden = !text;
}

// A servo that answers at another rate than the line's (the server names it): the message offers the line at it.
function reopenAt(baud) {
  return { label: `Reopen the line at ${baud.toLocaleString("en-US")} baud`, run: async () => {
    showServos([]); $("#scan-summary").textContent = "";  // the servos found were the line's at its old rate
    const s = await api("/api/connect", { baud });
    showStatus(s); $("#baud-select").value = String(s.baud);
    if (location.hash.startsWith("#servo")) await loadServo();
    say(`the line is open at ${s.baud.toLocaleString("en-US")} baud`, "info");
    if (!$("#page-line").hidden) await scanLine();  // (offered by a scan that found nothing: scanned again here)
  } };
}

// A server refusing the token this page was opened with was started again (each start makes a new token unless
// one is given): what the page says, whether its socket or a button's request finds it first.
const TOKEN_REFUSED = "the configurator's server runs with another token now (it was started again): "
  + "open the address `ics35 web` printed, which carries it";

async function api(path, data) {
  const options = data === undefined ? {} : { method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify(data) };
  let response;
  try {
    response = await fetch(path, options);
  } catch (e) {
    const gone = "the configurator's server does not answer (was `ics35 web` stopped?)";
    say(gone);
    throw new Error(gone, { cause: e });  // (a caller showing the error beside its button says this, not "Failed to fetch")
  }
  const text = await response.text();
  let body = null;
  try { body = JSON.parse(text); } catch (e) { body = { error: text.trim() }; }
  if (!response.ok && body && body.kind === "WrongToken") body.error = TOKEN_REFUSED;  // (the page's own cookie: see below)
  if (!response.ok) {
    say(body && body.error ? body.error : `error ${response.status}`, "error", body && body.answers_at ? reopenAt(body.answers_at) : null);
    // The port's words (503) while it is gone: showStatus replaces them when the line is back.
    state.sayingLost = response.status === 503 && (body.kind === "PortLost" || !!(state.status && state.status.lost));
    // The status goes with the error: 400 and 409 were refused before anything was sent; a 502 or 504 may
    // have reached the servo, its answer lost (a caller that showed the request's effect early tells them apart).
    throw Object.assign(new Error(body.error), { status: response.status, reply: body });
  }
  return body;
}

// "servo 5", "servos 5, 6": IDs named in words.
function servosNamed(ids) {
  return `${ids.length > 1 ? "servos" : "servo"} ${ids.join(", ")}`;
}

function el(tag, props = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(props)) {
    if (k === "class") node.className = v; else if (k in node) node[k] = v; else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c instanceof Node ? c : document.createTextNode(c == null ? "" : String(c)));
  return node;
}

// A number box's value. An emptied box (or one with a letter typed in, which the browser gives as empty)
// is refused in words: JavaScript's +"" is 0, which would renumber a servo to ID 0 or move a joint at once.
function numberIn(box, what) {
  const text = box.value.trim();
  if (text === "") {
    const words = emptyWords(box, what);
    say(words);
    throw new Error(words);
  }
  return +text;
}

// Why a number box gives no value: empty, or holding what is no number ("--5", on show in the box, which the
// browser gives as empty: "give it a value" of a box with something in it read as the page not seeing it).
function emptyWords(box, what) {
  return box.validity && box.validity.badInput ? `${what}: not a number (what its box holds)` : `give ${what} a value`;
}

// A box for a whole number (an ID, an EEPROM field, a RAM value): a fraction is refused here, in the page's words.
function wholeIn(box, what) {
  const value = numberIn(box, what);
  if (Number.isInteger(value)) return value;
  const words = `${what} must be a whole number, not ${box.value.trim()}`;
  say(words);
  throw new Error(words);
}

// The IDs a box names ("1-12", "0,3 5-7", "all"), read by the server by the command line's rule; its refusal is
// said (and thrown, as api() does, for the caller to stop at).
async function idsIn(text) {
  return (await api(`/api/ids?text=${encodeURIComponent(text)}`)).ids;
}

// ---------------------------------------------------------------- pages

function show() {
  const [page, arg] = (location.hash.slice(1) || "line").split("/");
  for (const section of document.querySelectorAll(".page")) section.hidden = section.id !== `page-${page}`;
  for (const a of document.querySelectorAll("nav a")) a.classList.toggle("active", a.getAttribute("href") === `#${page}`);
  say("");
  if (page !== "servo") leaveServo().catch(() => {});
  // (A failed read is said by api(): not again as an uncaught error in the console.)
  if (page === "servo" && shownStill(arg)) backToServo();
  else if (page === "servo" && arg === undefined && typedStill()) backToTyped();
  else if (page === "servo" && arg !== undefined) { $("#servo-id").value = arg; loadServo().catch(() => {}); }
  if (page === "many") { fillManyFields(); showManyLast().catch(() => {}); }
  showSimBanner();
  socketSend();
}

// The pages' line is simulated: said over every page but a robot's on hardware (whose question, while the pages
// stand in on sim://, frees real joints: "nothing here moves real hardware" would be false there).
function showSimBanner() {
  const s = state.status;
  if (!s) return;
  const robotPage = (location.hash.slice(1) || "line").split("/")[0] === "robot";
  const realRobot = Boolean(s.robot) && s.robot.lines.some((l) => !l.simulated);
  $("#sim-banner").hidden = !s.simulator || (robotPage && realRobot);
}

function showStatus(s) {
  state.status = s;
  showSimBanner();
  showSimHint(s.simulator ? s.robot_line : null);
  $("#lost-banner").hidden = !s.lost;
  // A robot's line comes back by itself, but the robot it stopped waits for the person's Reconnect.
  $("#lost-banner").textContent = s.robot_line
    ? `The robot's line ${s.robot_line} lost its port: plug it back in (the line reopens by itself; the robot waits), then press Reconnect on the Robot page`
    : "The port is lost: reconnecting as soon as it returns";
  showRobotLines(s.robot);
  $("#scan-progress").hidden = !s.scanning;
  $("#servo-table").classList.toggle("stale", !!s.lost || !s.connected);  // the last values read, not now's
  const where = (s.robot_line ? `the robot's line ${s.robot_line}: ` : "") + `${s.port} at ${s.baud} baud`;
  // A search of the other rates (after nothing answered) says which it tries: each may cost a whole allowance.
  const line = s.connected ? (s.lost ? `${where}: LOST` : where) : `not connected${s.error ? ": " + s.error : ""}`;
  $("#line-status").textContent = s.searching ? `${line} (${s.searching})` : line;
  // (What to do once back is the lost action's when it left something to look at first: see writeEeprom.)
  if (state.sayingLost && s.connected && !s.lost) say(`the line is back (${s.port}): ${state.backThen || "try again"}`, "info");
  // Motion the server switched off (a lost port; a live plot that took the servo over and freed it). Not
  // over a tick the server has yet to take: a status pushed meanwhile still says motion is off; nor from a
  // status sent before the server's answer to it (counting fewer changes of motion), come after it.
  const motionNow = !state.servoMotionAsked && (s.motion_switches ?? 0) >= state.motionSeen;
  const off = (s.motion_off || {})[state.servoLoaded];
  if (off && $("#motion-switch").checked && motionNow) {
    $("#motion-switch").checked = false; setMotion(false);
    if ($("#message").hidden) say(`motion is off for servo ${state.servoLoaded}: ${off}; switch it on again to jog (it holds the servo where it stands)`, "info");
  }
  // Switched off by another page (its page opened in another tab): this one shows it locked too. Not over
  // a tick the server has yet to take.
  const on = (s.motion_on || []).includes(state.motionFor);
  if (!on && $("#motion-switch").checked && motionNow) {
    $("#motion-switch").checked = false; setMotion(false);
    const words = `motion was switched off for servo ${state.motionFor} (by another page); switch it on again to jog`;
    if ($("#message").hidden) say(words, "info");
  }
  if (!$("#port-input").value) showLineInBoxes(s);
  if (!s.live) liveStopped();
}

// ---- Line

// The Port and Baud boxes naming the line a status `s` says is open.
function showLineInBoxes(s) {
  $("#port-input").value = s.port; $("#baud-select").value = String(s.baud);
}

// With --robot: the robot's lines on the Line page and the Robot page, so either leads to the other.
// A robot's line has the port its file gives it (--port opens another line beside the robot's), so the banner
// over one sends a builder to that file for hardware.
function showSimHint(robotLine) {
  const key = robotLine || "";
  if (state.simHintShown === key) return;
  state.simHintShown = key;
  $("#sim-hint").replaceChildren(...(robotLine
    ? ["for that: ", el("code", {}, 'port = "/dev/ttyUSB0"'), ` in the robot file's [lines.${robotLine}]`]
    : ["start with ", el("code", {}, "ics35 web --port /dev/ttyUSB0"), " for that"]));
}

function showRobotLines(robot) {
  $("#robot-link").hidden = !robot;
  $("#robot-lines").hidden = !robot;
  const key = robot ? JSON.stringify(robot.lines) : "";
  if (!robot || state.robotLinesShown === key) return;
  state.robotLinesShown = key;
  $("#robot-lines-table tbody").replaceChildren(...robot.lines.map((l) => el("tr", { "data-line": l.name }, el("td", {}, l.name),
    el("td", {}, l.port), el("td", {}, l.baud),
    el("td", {}, el("button", { type: "button", onclick: () => useRobotLine(l.name, true).catch(() => {}) }, "use")))));
  $("#robot-line-links").replaceChildren("Its lines:", ...robot.lines.map((l) => el("button", { type: "button", "data-line": l.name,
    title: `${l.port} at ${l.baud} baud`, onclick: () => { location.hash = "#line"; useRobotLine(l.name, true).catch(() => {}); } },
    `${l.name}: its servos on the Line page`)));
}

async function useRobotLine(name, scan = false) {
  const s = await api("/api/connect", { robot_line: name });
  showStatus(s); showServos([]);
  showLineInBoxes(s);
  say(`working on the robot's line ${name} (${s.port}); the robot keeps streaming it`, "info");
  if (scan) await scanLine();
}

async function openJoint(line, id) {
  if (!state.status || state.status.robot_line !== line) await useRobotLine(line);
  location.hash = `#servo/${id}`;
}

async function loadPorts() {
  const found = await api("/api/ports");
  const list = $("#port-list"), body = $("#ports-table tbody");
  list.replaceChildren(el("option", { value: "sim://" }, "built-in simulator"));
  body.replaceChildren();
  for (const p of found.ports) {
    list.append(el("option", { value: p.device }, p.description));
    const pick = el("button", { type: "button", onclick: () => { $("#port-input").value = p.device; } }, "use");
    body.append(el("tr", {}, el("td", {}, p.device), el("td", {}, p.description || "-"), el("td", {}, p.usb_id || "-"),
      el("td", {}, p.kondo ? el("strong", {}, "Kondo adapter ") : "", pick)));
  }
  if (!found.ports.length) body.append(el("tr", {}, el("td", { colSpan: 4 }, "no serial port on this machine")));
  $("#port-notes").replaceChildren(...found.notes.map((n) => el("li", {}, n)));
}

// The IDs a scan found at the line's own rate: the ones the other pages can talk to now (one found at another rate
// would answer nothing there until the line is connected at its rate).
function servosHere() {
  return state.servos.filter((s) => !state.status || s.baud === state.status.baud).map((s) => s.id);
}

function showServos(servos) {
  state.servos = servos;
  // The Many servos page shown before the server said which servos were found (opened as the page loaded): its
  // box named none; it names them once they are known, unless the person typed in it.
  if ($("#many-fields tbody").children.length && !state.manyIdsTyped && !$("#many-ids").value) {
    $("#many-ids").value = servosHere().join(",");
  }
  $("#servo-notes").hidden = !servos.length;
  const body = $("#servo-table tbody");
  // Each servo's row kept from one refresh to the next (about once a second), its cells written anew: a row made
  // anew each time took its "open" link away under a click whose press and release straddled a refresh.
  const before = new Map([...body.children].map((tr) => [tr.dataset.key, tr]));
  const rows = [];
  for (const s of servos) {
    // A servo that stopped answering: said in words (the library's, with the bytes sent, on hover; its
    // Servo page tells why), and no value from before shown as if read now.
    const silent = !!s.telemetry_error;
    // Found at another rate (a scan at every rate): the line reads only the servos at its own.
    const lineBaud = state.status && state.status.baud;
    const elsewhere = !silent && lineBaud && s.baud !== lineBaud && s.temperature_c === undefined;
    const temp = silent ? (s.garbled ? `answers garbled: two servos sharing ID ${s.id}?` : "not answering (open it to see why)")
      : elsewhere ? `not read: the line is at ${lineBaud} baud (Connect at ${s.baud} to read it)`
      : s.temperature_c === undefined ? "…" : s.temperature_text;
    const current = silent || elsewhere ? "-" : s.current === undefined ? "…" : String(s.current);
    const ics = elsewhere ? "-" : s.protocol === undefined ? "…" : s.protocol.replace("ICS ", "");
    const position = silent || elsewhere ? "-" : s.protocol === undefined ? "…" : s.position ?? "not read";
    const texts = [s.id, s.baud + (s.baud_pending ? " (EEPROM names another rate)" : ""), ics, position, temp, current];
    const titles = [null, null, null, s.position_note || "", s.telemetry_error || "", null];
    const key = `${s.id}@${s.baud}`;
    let row = before.get(key);
    if (!row) {
      row = el("tr", { "data-id": s.id, "data-key": key }, el("td", {}), el("td", {}), el("td", { class: "ics" }),
        el("td", { class: "position" }), el("td", { class: "temp" }), el("td", { class: "current" }),
        el("td", {}, el("a", { href: `#servo/${s.id}` }, "open")));
    }
    texts.forEach((text, k) => {
      const cell = row.children[k];
      if (cell.textContent !== String(text)) cell.textContent = String(text);
      if (titles[k] !== null) cell.title = titles[k];
    });
    rows.push(row);
  }
  if (rows.length !== body.children.length || rows.some((row, k) => body.children[k] !== row)) body.replaceChildren(...rows);
}

// Baud rates in words: "625,000 or 1,250,000".
function rateList(rates) {
  const words = rates.map((rate) => rate.toLocaleString("en-US"));
  return words.length > 1 ? `${words.slice(0, -1).join(", ")} or ${words[words.length - 1]}` : words.join("");
}

async function scanLine() {
  const bauds = $("#scan-all-bauds").checked ? [115200, 625000, 1250000] : null;
  const text = $("#scan-ids").value.trim();
  let ids = null;  // every ID
  try {
    if (text) ids = await idsIn(text);
  } catch (e) {
    $("#scan-summary").textContent = "nothing was scanned (the message above says why)";  // (as a refused scan)
    return;
  }
  $("#scan-btn").disabled = true;
  $("#scan-summary").textContent = "scanning…";
  try {
    const report = await api("/api/scan", { bauds, ids });
    showServos(report.servos);
    const notes = [];
    if (report.silent) notes.push("nothing came back at all, not even the echo: check power, wiring and the adapter");
    if (report.echo_wrong) notes.push(`the echo setting looks wrong for this interface (${report.echo_wrong})`);
    for (const g of report.garbled) notes.push(`ID ${g.id} at ${g.baud} answered garbled twice (two servos sharing it?)`);
    for (const [b, why] of Object.entries(report.skipped)) notes.push(`${b} baud skipped: ${why}`);
    // The echo came back but no servo answered (nor one at another rate, said below): their power, most often.
    // The other rates the server then looked at (a whole allowance each) are named: they need no scan of their own.
    if (!report.servos.length && !report.garbled.length && !report.silent && !report.lost && !report.answers_at) {
      const rate = state.status ? `${state.status.baud.toLocaleString("en-US")} baud` : "the line's rate";
      const tried = report.rates_tried || [];
      const elsewhere = tried.length ? `, nor any device at ${rateList(tried)} baud` : "";
      notes.push(`no servo answered at ${bauds ? "any baud rate" : rate}${elsewhere}: ` +
        "check their power (6-12 V on the servo line, not just USB) and wiring" +
        (bauds || tried.length ? "" : "; a servo set to another rate answers only at it (tick “every baud rate”)"));
    }
    if (report.lost) {  // the servos found before the line went are listed; the rest of the scan did not run
      say(report.lost);
      state.sayingLost = true;  // (showStatus says when the line is back)
      $("#scan-summary").textContent = `${report.servos.length} servo(s) found before the line was lost; ` +
        `scan again when it is back. ${notes.join("; ")}`;
      return;
    }
    $("#scan-summary").textContent = `${report.servos.length} servo(s) found. ${notes.join("; ")}`;
    if (report.answers_at) {  // nothing at the line's rate, something at another: offer the line at that one
      const at = state.status ? ` at ${state.status.baud.toLocaleString("en-US")} baud` : "";
      say(`no servo answered${at}, but a device does at ${report.answers_at.toLocaleString("en-US")} baud`, "error",
        reopenAt(report.answers_at));
    }
  } catch (e) {
    // A refusal (IDs out of range, a robot streaming) came before anything went on the wire: not a scan cut short.
    const refused = e.status === 400 || e.status === 409;
    $("#scan-summary").textContent = `${refused ? "nothing was scanned" : "the scan did not finish"} ` +
      "(the message above says why)";
    throw e;
  } finally { $("#scan-btn").disabled = false; }
}

// ---- Servo

// The servo the page shows (the last one read): every action acts on it, never on an ID typed in the box and
// not read (the page showed one servo's values and wrote another's: new servos all read alike).
function servoId() {
  const id = state.servoLoaded;
  if (id === null || id === undefined) {
    // (just after a Read that failed, "read a servo first" read as if Read had not been pressed)
    const failed = state.readFailed;
    const words = failed === null || failed === undefined
      ? "read a servo first" : `no servo is shown: the read of servo ${failed} failed; read a servo that answers first`;
    say(words);
    throw new Error(words);
  }
  return id;
}

function robotNote(id) {
  const line = state.status && state.status.robot_line;
  const joint = line && state.robot ? state.robot.joints.find((j) => j.line === line && j.id === id) : null;
  $("#servo-robot-note").hidden = !line;
  $("#servo-robot-note").textContent = line ? `Servo ${id} ${joint ? `drives the joint ${joint.name}` : "is"} on the robot's line ${line}, which the robot keeps streaming: ` +
    "read and configure it here; move or free it on the Robot page." : "";
}

// The page shows motion off for a servo it opens or leaves: the server is told so, and no jog (from another
// tab) moves a servo whose page said it was locked.  (It keeps holding: Free lets go.)
async function motionOff(id) {
  if (id === null || id === undefined || Number.isNaN(id)) return;  // (asked even before the first status came)
  state.servoMotionAsked += 1;
  try {
    await fetch(`/api/servo/${id}/motion`, { method: "POST", headers: { "content-type": "application/json" },
      body: JSON.stringify({ enabled: false }) });
  } catch (e) { /* the server is gone: the WebSocket says so */ } finally { state.servoMotionAsked -= 1; }
}

async function leaveServo() {
  const [shown, on] = [state.servoLoaded, state.motionFor];
  $("#motion-switch").checked = false; setMotion(false);
  state.motionFor = null;
  // Left, its page acts on no servo until one is read again: what it still shows is the last servo's, and a
  // click while the next one's values load must not act on that one (nor say it loaded: see loadServo).
  state.servoLoaded = null;
  delete $("#page-servo").dataset.loaded;
  await motionOff(shown);
  if (on !== shown) await motionOff(on);  // (the switch acts on the servo shown: never expected, but kept off)
}

// The servo the page still shows, read on the line open now: the Servo link, or the browser's Back to its page
// (``arg``, its ID in the address), come back to it.
function shownStill(arg) {
  const shown = state.shown, s = state.status;
  if (!shown || !s || shown.port !== s.port || shown.baud !== s.baud) return false;
  return arg === undefined || arg === String(shown.id);
}

// What was typed for a servo whose read failed (the page shows no servo then), on the line open now.
function typedStill() {
  const typed = state.typedFor, s = state.status;
  return !!typed && !!s && typed.port === s.port && typed.baud === s.baud;
}

// Back on the Servo page after its read failed: that servo read again, what was typed kept (see loadServo); the
// page came back empty, nothing read, the typed values back only at Read.
function backToTyped() {
  const id = state.typedFor.id;
  $("#servo-id").value = id;
  history.replaceState(null, "", `#servo/${id}`);
  loadServo().catch(() => {});
}

// Back on the page of the servo it shows: that servo read again (another page may have written to it meanwhile),
// with what was typed in its boxes and not written kept (read again, they were lost); a Show changes diffs them
// against the servo as it is now.
function backToServo() {
  const id = state.shown.id;
  $("#servo-id").value = id;
  history.replaceState(null, "", `#servo/${id}`);
  loadServo(typedEdits()).catch(() => {});
}

// What was typed in the EEPROM boxes and not written: {field: value as typed}, a flag's as {"flag-NAME": ticked}.
function typedEdits() {
  const typed = {};
  for (const f of state.eeprom?.fields ?? []) {
    for (const flag of f.flags ?? []) {
      const box = document.querySelector(`[name=flag-${flag.name}]`);
      if (box && !flag.read_only && box.checked !== flag.on) typed[`flag-${flag.name}`] = box.checked;
    }
    const box = f.flags ? null : document.querySelector(`#eeprom-table [name=${f.name}]`);
    if (box && box.value !== String(f.value)) typed[f.name] = box.value;
  }
  return typed;
}

async function loadServo(typed = {}) {
  const asked = $("#servo-id").value.trim(), mine = (state.loads ?? 0) + 1;  // (readServo counts this load)
  try {
    await readServo(typed);
  } catch (e) {
    // The servo did not answer (or answered garbled): what an action on no servo shown then says, unless a
    // later Read overtook this one.
    if ((e.status === 502 || e.status === 504) && state.loads === mine) state.readFailed = asked;
    throw e;
  }
}

async function readServo(typed) {
  const id = wholeIn($("#servo-id"), "the servo's ID");
  // (its tables are another read's from here on; a read that fails keeps what was typed for the next of this servo)
  const kept = state.typedFor && state.typedFor.id === id && !Object.keys(typed).length ? state.typedFor.typed : typed;
  const line = { port: state.status && state.status.port, baud: state.status && state.status.baud };
  state.shown = null; state.typedFor = Object.keys(kept).length ? { id, typed: kept, ...line } : null;
  // Each load has its number: one overtaken by a later load (Read pressed again, another servo's page) stops at
  // its next step, so the page never ends on the earlier servo, showing its values and acting on it.
  const mine = (state.loads = (state.loads ?? 0) + 1);
  const overtaken = () => mine !== state.loads;
  state.readFailed = null;
  await leaveServo();
  await motionOff(id);
  if (overtaken()) return;
  robotNote(id);
  state.servoLoaded = null;  // no position reads until this servo's page is shown
  $("#jog-position").textContent = "-"; $("#jog-position-note").textContent = ""; state.positionHow = null;
  targetSent(null);  // where this page last sent a servo: none yet
  // A file chosen for the last servo goes too: shown beside a Restore button left disabled, and chosen again
  // (no change to the browser) it would do nothing.
  $("#restore-file").value = "";
  // A tick allowing an ID or baud change is for one write to the servo it was ticked for: kept, it let the next
  // servo's write or restore (an old backup at another rate) change its ID or rate with no tick of its own.
  for (const tick of ["#allow-id-change", "#allow-baud-change", "#restore-id"]) $(tick).checked = false;
  $("#diff").replaceChildren(); $("#write-result").replaceChildren(); $("#write-btn").disabled = true; state.plan = null;
  // Another servo's values, or this one's from before a failed read, must not stay on show as if read now.
  state.eeprom = null;
  $("#eeprom-table tbody").replaceChildren(); $("#ram-table tbody").replaceChildren(); state.ram = null;
  $("#restore-diff").replaceChildren(); $("#restore-result").replaceChildren(); $("#restore-btn").disabled = true;
  const eeprom = await api(`/api/servo/${id}/eeprom`);
  if (overtaken()) return;
  state.eeprom = eeprom;
  const body = $("#eeprom-table tbody");
  body.replaceChildren();
  for (const f of state.eeprom.fields) {
    let input;
    if (f.flags) {
      input = el("span", {}, ...f.flags.map((flag) => el("label", { title: flag.read_only ? "read-only: reports the servo's state" : "" },
        el("input", { type: "checkbox", name: `flag-${flag.name}`, checked: flag.on, disabled: flag.read_only }), ` ${flag.name} `)));
    } else if (f.choices) {
      input = el("select", { name: f.name }, ...f.choices.map((c) => el("option", { value: c, selected: c === f.value }, c)));
    } else {
      input = el("input", { type: "number", name: f.name, value: f.value, min: f.low, max: f.high, step: f.even ? 2 : 1 });
    }
    const range = f.low === undefined ? "" : `${f.low}..${f.high}${f.even ? " even" : ""}`;
    body.append(el("tr", { "data-field": f.name }, el("td", {}, f.name), el("td", {}, input), el("td", {}, f.unit), el("td", {}, range), el("td", { class: "meaning" }, f.meaning)));
  }
  for (const [name, value] of Object.entries(kept)) {  // (typed before it was read again: see backToServo)
    const box = document.querySelector(`#eeprom-table [name=${name}]`);
    if (box && box.type === "checkbox") box.checked = value; else if (box) box.value = value;
  }
  const ram = await api(`/api/servo/${id}/ram`);
  if (overtaken()) return;
  showRam(ram);
  const limits = state.eeprom.fields.filter((f) => f.name.startsWith("pulse_limit")).map((f) => f.value);
  state.limits = [Math.min(...limits), Math.max(...limits)];
  $("#jog-slider").min = state.limits[0]; $("#jog-slider").max = state.limits[1];
  $("#jog-limits").textContent = `${state.limits[0]}..${state.limits[1]}`;
  $("#motion-switch").checked = false; setMotion(false);
  state.servoLoaded = id;
  $("#page-servo").dataset.loaded = String(id);  // (read: what a test, or a person's script, can wait for)
  state.shown = { id, port: state.status && state.status.port, baud: state.status && state.status.baud };
  state.typedFor = null;
  pollPosition();
}

// "reported": the servo's position read again while its page is open. A position command's reply is where
// the servo stood when the command arrived, before it moved; the server reads the position without moving
// or freeing it (ICS 3.6), or says what the number is when it cannot (ICS 3.5).
const POSITION_PERIOD_MS = 500;

async function pollPosition() {
  const id = state.servoLoaded;
  if (id === null || id === undefined || $("#page-servo").hidden) return;
  let response, body;
  try {
    response = await fetch(`/api/servo/${id}/position`);
    body = await response.json();
  } catch (e) { return; }  // the server is gone: the WebSocket says so
  if (id !== state.servoLoaded) return;  // another servo's page meanwhile
  if (state.serverGone || state.tokenRefused) return;  // (its words, from serverGoneHere, stay until it is back)
  if (!response.ok) { $("#jog-position-note").textContent = `not read now: ${body.error}`; return; }
  state.positionHow = body.how;
  if (body.position !== null) $("#jog-position").textContent = body.position;
  $("#jog-position-note").textContent = body.note;
}

async function positionLoop() {
  await pollPosition();
  setTimeout(positionLoop, POSITION_PERIOD_MS);  // one read at a time: a slow line is not queued up
}

function editedFields() {
  const changes = {};
  let flags = 0;
  for (const f of state.eeprom.fields) {
    if (f.flags) {
      for (const flag of f.flags) if (!flag.read_only && document.querySelector(`[name=flag-${flag.name}]`).checked) flags |= flag.bit;
      const writable = f.flags.filter((x) => !x.read_only).reduce((a, x) => a | (x.on ? x.bit : 0), 0);
      if (flags !== writable) changes.flags = flags;
      continue;
    }
    const value = wholeIn(document.querySelector(`#eeprom-table [name=${f.name}]`), f.name);
    if (value !== f.value) changes[f.name] = value;
  }
  return changes;
}

function allowances() {
  return { allow_id_change: $("#allow-id-change").checked, allow_baud_change: $("#allow-baud-change").checked };
}

function diffTable(plan) {
  const note = plan.note ? [el("p", {}, plan.note)] : [];  // what the write leaves as the servo has it
  if (!plan.diff.length) return el("div", {}, el("p", {}, "no change: the servo already has these values"), ...note);
  const rows = plan.diff.map((d) => el("tr", { class: "changed" }, el("td", {}, d.name), el("td", {}, d.now), el("td", {}, d.new)));
  const extra = [];
  if (plan.flags_set.length) extra.push(el("p", {}, `flags set: ${plan.flags_set.join(", ")}`));
  if (plan.flags_cleared.length) extra.push(el("p", { class: "bad" }, `flags CLEARED: ${plan.flags_cleared.join(", ")}`));
  extra.push(...note);
  if (plan.refusal) extra.push(el("p", { class: "refusal" }, `refused: ${plan.refusal}`));
  return el("div", {}, el("table", { class: "grid diff" }, el("thead", {}, el("tr", {}, el("th", {}, "field"), el("th", {}, "now"), el("th", {}, "new"))), el("tbody", {}, ...rows)), ...extra);
}

function resultText(result) {
  if (!result.written) return el("p", { class: "good" }, "nothing written: the servo already had these values");
  const parts = [result.verified ? "written and verified by reading it back" : "written, but the read-back differs"];
  if (result.answering_ids.length) parts.push(`answering IDs now: ${result.answering_ids.join(", ")}`);
  if (result.new_rate_answers !== null) parts.push(result.new_rate_answers ? "it answers at the new rate" : "not at the new rate yet (power-cycle it)");
  const done = el("p", { class: result.verified ? "good" : "bad" }, parts.join("; "));
  return result.note ? el("div", {}, done, el("p", {}, result.note)) : done;
}

async function planWrite() {
  $("#write-result").replaceChildren();  // an earlier write's outcome is not this one's
  $("#write-btn").disabled = true;
  state.plan = await api(`/api/servo/${servoId()}/plan`, { changes: editedFields(), ...allowances() });
  // Refused for a change of ID or rate that a tick allows (the server says which allowance): said which tick.
  const ticks = [["allow_id_change", "#allow-id-change", "allow ID change"], ["allow_baud_change", "#allow-baud-change", "allow baud change"]]
    .filter(([allowance, box]) => state.plan.allowed_by === allowance && !$(box).checked)
    .map(([, , label]) => el("p", {}, `tick “${label}” to write it, then Show changes again`));
  $("#diff").replaceChildren(diffTable(state.plan), ...ticks);
  $("#write-btn").disabled = !state.plan.diff.length || !!state.plan.refusal;
}

// A box changed after Show changes: Write writes what the boxes say, so the diff shown is not what it would write.
function planStale() {
  if (!state.plan) return;
  state.plan = null;
  $("#write-btn").disabled = true;
  $("#diff").append(el("p", { class: "refusal" }, "changed since this diff: press Show changes again to write it"));
}

// After a write that gave the servo another ID, the page is that ID's: read at the old one, the servo would
// not answer (and the page would look for it at the other rates), hiding the write's outcome.
function followNewId(result) {
  const change = result.written && result.diff.find((d) => d.name === "servo_id");
  const old = servoId();
  $("#servo-id").value = change ? change.new : old;  // (read next: the servo written, whatever the box said)
  if (!change) return `servo ${old}`;
  history.replaceState(null, "", `#servo/${change.new}`);  // (no hashchange: this page reads it next)
  return `servo ${old} is now servo ${change.new}`;
}

// Said after a write or restore that read the servo again, which switched its motion off (its limits may be new).
function motionOffAfter(wasOn) {
  return wasOn ? "; motion is off now (it was read again): switch it on to jog, which holds it where it stands" : "";
}

// The servo read again after a write or restore: where that read meets a lost port, what to do once the line is
// back is to read it, not "try again" (which invited a second write of one already done).
async function readAfterWrite(id, result) {
  try {
    await loadServo();
  } catch (e) {
    if (state.sayingLost) {
      const done = result.written ? (result.verified ? "the write was verified" : "the write's read-back differed") : "nothing was written";
      state.backThen = `${done} before the port went: press Read to show servo ${id} again`;
    }
    throw e;
  }
}

// A write's or restore's outcome on top (``done``: "written", "restored"; ``none``: what nothing to do is called).
function sayWritten(who, result, done, none, wasOn) {
  const what = result.written ? (result.verified ? `${done} and verified` : "read-back differs") : none;
  say(`${who}: ${what}${motionOffAfter(wasOn)}`, result.verified || !result.written ? "info" : "error");
}

async function writeEeprom() {
  const id = servoId(), typed = typedEdits();
  const request = { changes: editedFields(), ...allowances(), before: state.plan.before };
  let result;
  try {
    result = await api(`/api/servo/${id}/write`, request);
  } catch (e) {
    // Not refused (400, 409): the write may have reached the servo, which is read before writing again. The edits
    // stay through that read (in the boxes, for Show changes to diff against what the servo holds then).
    if (e.status !== 400 && e.status !== 409) state.typedFor = { id, typed };
    if (state.sayingLost) state.backThen = `read servo ${id} (Read) to see whether the write reached it; your edits are kept`;
    throw e;
  }
  $("#write-btn").disabled = true;
  const who = followNewId(result);
  const wasOn = $("#motion-switch").checked;
  // The outcome is shown whatever the read after it meets (the server stopped, the servo unplugged): hidden
  // behind that read's error, a verified write left the person guessing what the servo holds.
  // (the ID the servo answers as now: followNewId put it in the box; the page still shows the old one)
  try { await readAfterWrite(+$("#servo-id").value, result); } finally { $("#write-result").replaceChildren(resultText(result)); }
  sayWritten(who, result, "written", "nothing to write", wasOn);
}

// The name a backup of ids is offered under, as the server names it: servo-05.json, servos-01-17.json.
function backupName(ids) {
  const two = (i) => String(i).padStart(2, "0");
  return ids.length === 1 ? `servo-${two(ids[0])}.json` : `servos-${two(ids[0])}-${two(ids[ids.length - 1])}.json`;
}

// A backup the server made, downloaded as the file name.
function download(doc, name) {
  const blob = new Blob([JSON.stringify(doc, null, 2) + "\n"], { type: "application/json" });
  const link = el("a", { href: URL.createObjectURL(blob), download: name });
  document.body.append(link); link.click(); link.remove();
}

async function backupServo() {
  const doc = await api(`/api/servo/${servoId()}/backup`);
  download(doc, backupName([servoId()]));
  say(`servo ${servoId()}'s EEPROM saved as ${backupName([servoId()])}`, "info");
}

async function planRestore() {
  const file = $("#restore-file").files[0];
  $("#restore-btn").disabled = true;
  // The last file's diff goes before this one is read: left under the words refusing this one (not JSON, not a
  // backup, a failed read), it named the other file as if it were the one chosen.
  $("#restore-result").replaceChildren(); $("#restore-diff").replaceChildren(); state.restore = null;
  if (!file) return;
  let doc;
  try { doc = JSON.parse(await file.text()); } catch (e) {
    say(`${file.name} is no EEPROM backup: not JSON (a backup is the .json file Back up saves)`); return;
  }
  const request = { doc, restore_id: $("#restore-id").checked, keep_baud: $("#restore-keep-baud").checked,
    allow_baud_change: $("#allow-baud-change").checked };
  let plan;
  try {
    plan = await api(`/api/servo/${servoId()}/restore/plan`, request);
  } catch (e) {
    // Refused for what the file holds (damaged, or none of this servo in a file of several): the file named, as
    // its not-JSON refusal names it.
    if (e.status === 400) say(`${file.name}: ${e.message}`);
    throw e;
  }
  state.restore = { ...request, before: plan.before };
  const note = plan.file_holds
    ? el("p", {}, `${file.name} holds the backups of servos ${plan.file_holds}: servo ${servoId()}'s is restored`)
    : plan.saved_id !== servoId() && !request.restore_id ? el("p", {}, `${file.name} is a backup of ID ${plan.saved_id}; servo ${servoId()} keeps its ID`) : "";
  const baud = plan.allowed_by === "allow_baud_change"
    ? el("p", {}, "to restore the rest and keep the servo at its rate, tick “keep its baud rate”") : "";
  $("#restore-diff").replaceChildren(note, diffTable(plan), baud);
  $("#restore-btn").disabled = !plan.diff.length || !!plan.refusal;
}

async function restoreServo() {
  const result = await api(`/api/servo/${servoId()}/restore`, state.restore);
  $("#restore-btn").disabled = true;
  const who = followNewId(result);  // "also its ID": the servo answers at the backup's
  const wasOn = $("#motion-switch").checked;
  try { await readAfterWrite(+$("#servo-id").value, result); } finally { $("#restore-result").replaceChildren(resultText(result)); }  // (as a write's)
  // (on top too, as a write's: beside the button alone, below the diff, it went unseen)
  sayWritten(who, result, "restored", "nothing to restore", wasOn);
}

async function writeRam() {
  const param = $("#ram-param").value;
  $("#ram-result").textContent = "";  // (an earlier write's success stood beside this one's refusal)
  const named = $("#ram-param").selectedOptions[0].textContent.replace(/ \(.*$/, "");  // ("current limit")
  const reply = await api(`/api/servo/${servoId()}/ram/write`, { param, value: wholeIn($("#ram-value"), named) });
  $("#ram-result").textContent = `servo ${servoId()} ${param} = ${reply.value} in RAM (lost at power-off)`;
  showRam(await api(`/api/servo/${servoId()}/ram`));
}

function showRam(ram) {
  state.ram = ram;
  // Each value in words (the current's sign is its direction, the temperature smaller when hotter), not as read.
  const rows = Object.entries(ram).filter(([k]) => k !== "shown");
  $("#ram-table tbody").replaceChildren(...rows.map(([k, v]) => el("tr", {}, el("th", {}, k), el("td", {}, ram.shown?.[k] ?? v))));
  ramBox();
}

// The RAM box starts at what the servo has for the parameter chosen (it said 127 whatever the servo had, and
// Write to RAM, pressed to see what it does, set that): stretch and speed as read from its RAM; the limits
// cannot be read there, so what the servo starts with, its EEPROM's.  Its range is the parameter's own.
function ramBox() {
  const choice = $("#ram-param").selectedOptions[0];
  const box = $("#ram-value");
  box.max = choice.dataset.max;
  const fromEeprom = (state.eeprom?.fields ?? []).find((f) => f.name === choice.value);
  const value = state.ram && choice.value in state.ram ? state.ram[choice.value] : fromEeprom?.value;
  if (value !== undefined) box.value = value;
}

function setMotion(on) {
  for (const id of ["#jog-minus", "#jog-plus", "#jog-slider"]) $(id).disabled = !on;
}

async function toggleMotion() {
  const on = $("#motion-switch").checked;
  state.servoMotionAsked += 1;
  try {
    const reply = await api(`/api/servo/${servoId()}/motion`, { enabled: on, page: PAGE });
    $("#motion-switch").checked = reply.enabled;  // (the server's answer, whatever was pushed meanwhile)
    state.motionSeen = Math.max(state.motionSeen, reply.motion_switches ?? 0);
    setMotion(reply.enabled);
    state.motionFor = reply.enabled ? servoId() : null;  // (the servo the switch is on for)
    if (reply.enabled) {  // held where it stands: the slider starts there
      targetSent(reply.position);
      $("#jog-position").textContent = reply.position;
    }
  } catch (e) { $("#motion-switch").checked = false; setMotion(false); } finally { state.servoMotionAsked -= 1; }
}

// The jog's target as shown: a number sent (or where motion was switched on), "-" for none, or a target not
// confirmed (the jog's answer lost: the servo may be going there, or still to the one before; "server": the
// server never answered, so the jog may not even have left the browser).
function showTarget(position, uncertain = false) {
  const box = $("#jog-target");
  box.textContent = position === null ? "-" : uncertain ? `${position}? (not confirmed)` : String(position);
  box.title = uncertain === "server" ? `the server did not answer the jog to ${position}: it may not have reached the servo, or reached it with its answer lost`
    : uncertain ? `the jog to ${position} was sent but its answer was lost: the servo may be going there, or still holding the target before` : "";
  box.classList.toggle("uncertain", Boolean(uncertain));
  if (position !== null) $("#jog-slider").value = position;
}

// The last target sent to the servo shown (null: none), and whether it is only perhaps sent.
function targetSent(position, uncertain = false) {
  state.jogSent = { position, uncertain };
  showTarget(position, uncertain);
}

async function jog(position) {
  const [low, high] = state.limits, wanted = Math.round(position);
  position = Math.max(low, Math.min(high, wanted));
  // (stopped at the limit with a word: +100 there did nothing, and nothing said why)
  if (position !== wanted) {
    say(`${wanted} is past servo ${servoId()}'s pulse limit ${position} (its EEPROM): the target stops there`, "info");
  }
  const mine = (state.jogs = (state.jogs ?? 0) + 1);
  showTarget(position);  // at once, so a drag or clicks in a row feel direct; taken back if refused
  let reply;
  try {
    reply = await api(`/api/servo/${servoId()}/move`, { position });
  } catch (e) {
    const latest = mine === state.jogs;  // (a later jog shows its own target meanwhile)
    if (e.reply && e.reply.freed) {  // sent, but its reply showed the servo off its way: the server freed it
      targetSent(null);
      $("#jog-position").textContent = e.reply.position;
      $("#motion-switch").checked = false; setMotion(false);
      state.motionFor = null;
    } else if (e.status === 400 || e.status === 409) {  // refused, nothing sent: the last target sent stands
      const sent = state.jogSent ?? { position: null, uncertain: false };
      if (latest) showTarget(sent.position, sent.uncertain);
    } else {  // 502, 504, a lost port or server: it may have gone out
      const uncertain = e.status === undefined ? "server" : true;  // (no status: the server never answered)
      state.jogSent = { position, uncertain };
      if (latest) showTarget(position, uncertain);
    }
    throw e;
  }
  state.jogSent = { position, uncertain: false };
  if (mine === state.jogs) showTarget(position);
  // The reply is where it stood before this move: shown only for a servo whose position is not read again.
  if (state.positionHow !== "read") $("#jog-position").textContent = reply.position;
}

async function torque(what) {
  const reply = await api(`/api/servo/${servoId()}/${what}`, {});
  $("#jog-position").textContent = reply.position ?? "-";
  // Target: where the servo was last sent; freed, none ("target 11400" stood beside a servo let go at 8988); held
  // here, where it stood (null: it did not answer now, and no target is known).
  if (what === "free") targetSent(null);
  else if (reply.position !== null && reply.position !== undefined) targetSent(reply.position);
  if (what === "free") { $("#motion-switch").checked = false; setMotion(false); }
  const where = reply.position === null
    ? ": not answering now (the live stream frees it once it answers)" : ` at ${reply.position}`;
  say(`servo ${servoId()}: ${what === "free" ? "free (torque off)" : "holding"}${where}`, "info");
}

// ---- ID

async function survey() {
  $("#survey-result").replaceChildren();
  const s = await api("/api/id/survey", {});
  $("#survey-result").replaceChildren(s.refusal
    ? el("p", { class: "refusal" }, `not safe to renumber: ${s.refusal}`)
    : el("p", { class: "good" }, `exactly one servo on the line, at ID ${s.lone_id} (${s.baud} baud)`));
}

async function renumber() {
  $("#id-result").replaceChildren();
  try {
    const r = await api("/api/id/write", { new_id: wholeIn($("#new-id"), "the new ID") });
    if (r.written && state.shown && state.shown.id === r.old_id) state.shown = null;  // (its page reads it anew)
    $("#id-result").replaceChildren(el("p", { class: "good" }, r.written ? `renumbered: ID ${r.old_id} is now ID ${r.new_id}, and answers` : `the servo already has ID ${r.new_id}`));
  } catch (e) {
    say("");  // (api() or wholeIn() said it on top too: once, beside the button, is enough)
    $("#id-result").replaceChildren(el("p", { class: "refusal" }, e.message));
  }
}

// ---- Many

const PROFILE_FIELDS = ["stretch_gain", "speed", "punch", "dead_band", "damping", "safe_timer", "temperature_limit", "current_limit", "response", "stretch_1", "stretch_2", "stretch_3"];

function fillManyFields() {
  const body = $("#many-fields tbody");
  if (body.children.length) return;
  if (!$("#many-ids").value) $("#many-ids").value = servosHere().join(",");
  for (const name of PROFILE_FIELDS) {
    body.append(el("tr", { "data-field": name }, el("td", {}, el("input", { type: "checkbox", name: `use-${name}` })), el("td", {}, name),
      el("td", {}, el("input", { type: "number", name: `value-${name}` })), el("td", { class: "range" })));
  }
  showManyRanges().catch(() => {});
}

// Each field's range, as the Servo page shows it (the library's, from the server): a value out of it is seen
// before Apply, not only refused by it.
async function showManyRanges() {
  const { fields } = await api("/api/many/fields");
  for (const f of fields) {
    const row = document.querySelector(`#many-fields tr[data-field=${f.name}]`);
    if (!row || f.low === undefined) continue;
    row.querySelector(".range").textContent = `${f.low}..${f.high}${f.even ? " even" : ""}`;
    Object.assign(row.querySelector("input[type=number]"), { min: f.low, max: f.high, step: f.even ? 2 : 1 });
  }
}

// The servos the Many servos page's box names, or undefined where it names none or they are refused (said why).
async function manyIds(what) {
  const text = $("#many-ids").value.trim();
  if (!text) { say(`name the servos to ${what} (e.g. 1-17), or scan the line first`); return undefined; }
  try { return await idsIn(text); } catch (e) { return undefined; }
}

async function applyMany() {
  // An earlier Apply's outcome goes first: it stood under this one's refusal as if this one had failed so.
  $("#many-results tbody").replaceChildren(); $("#many-errors").replaceChildren(); $("#many-last").textContent = "";
  const ids = await manyIds("change");
  if (!ids) return;
  const changes = {};
  for (const name of PROFILE_FIELDS) {
    if (!document.querySelector(`[name=use-${name}]`).checked) continue;
    const box = document.querySelector(`[name=value-${name}]`), text = box.value.trim();
    if (text === "") { say(`${emptyWords(box, name)}, or untick it`); return; }  // an empty box is not 0
    changes[name] = +text;
  }
  if (!Object.keys(changes).length) { say("tick at least one field to apply"); return; }
  const reply = await api("/api/many/apply", { ids, changes });
  $("#many-last").textContent = "";  // (a wait for "an Apply running" shown meanwhile was this one's)
  showManyResults(reply.results);
}

// The server's last Apply, shown on a page that has none of its own on show (reloaded while it ran, or another
// tab's): the servos were written whether a page heard the answer or not.  One still running is waited for.
async function showManyLast() {
  if ($("#many-results tbody").children.length) return;
  const { last } = await api("/api/many/last");
  if (!last || $("#many-results tbody").children.length || $("#page-many").hidden) return;
  const servos = servosNamed(last.ids);
  if (last.running) {
    $("#many-last").textContent = `an Apply to ${servos} is running, from this page or another: its outcome shows here when it ends`;
    clearTimeout(state.manyWait);  // (one wait: the page left and opened again meanwhile started another)
    state.manyWait = setTimeout(() => showManyLast().catch(() => {}), 500);
    return;
  }
  $("#many-last").textContent = `the last Apply (${servos}), from this page or another:`;
  showManyResults(last.results);
}

function showManyResults(results) {
  // The same words for several servos (a lost port, a line of absent IDs) said once, naming them all.
  const failed = new Map();
  for (const r of results) if (r.error) failed.set(r.error, [...(failed.get(r.error) || []), r.id]);
  $("#many-errors").replaceChildren(...[...failed].map(([words, who]) =>
    el("li", {}, `${servosNamed(who)}: ${words}`)));
  // (a write the servo took whose read-back failed is no "failed": it holds the new values, or part of them; nor is
  // one cut short as it went out, which may have reached it)
  const cutShort = (r) => ({ PortLost: " (port lost as it went)", ReplyTimeout: " (no answer)" })[r.kind] || "";
  const outcome = (r) => r.error ? (r.not_tried ? "not tried" : r.written ? "written, not verified"
    : r.maybe_written ? `may be written${cutShort(r)}: read it` : "failed (see above)")
    : r.written ? (r.verified ? "written, verified" : "read-back differs") : "already so";
  $("#many-results tbody").replaceChildren(...results.map((r) => el("tr", { "data-id": r.id }, el("td", {}, r.id),
    el("td", { class: r.error ? "bad" : "good", title: r.error || "" }, outcome(r)),
    el("td", {}, r.diff ? r.diff.map((d) => `${d.name} ${d.now}→${d.new}`).join(", ") : ""))));
}

// One file of every chosen servo's EEPROM. A servo that does not answer is left out, and the port lost part-way ends
// the reading: the file holds what was read all the same, and the list below the button names the servos it lacks.
async function backupMany() {
  const ids = await manyIds("back up");
  if (!ids) return;
  $("#many-backup-missing").replaceChildren();
  const doc = await api("/api/many/backup", { ids });
  // The same words for several servos (a lost port, a line of absent IDs) said once, naming them all.
  const missing = new Map();
  for (const m of doc.not_saved) missing.set(m.why, [...(missing.get(m.why) || []), m.servo_id]);
  $("#many-backup-missing").replaceChildren(...[...missing].map(([words, who]) =>
    el("li", { "data-ids": who.join(",") }, `${servosNamed(who)}: ${words}`)));
  const lacking = doc.not_saved.map((m) => m.servo_id);
  const notSaved = lacking.length ? `; not saved: ${servosNamed(lacking)} (see below)` : "";
  if (!doc.servos.length) { say(`nothing saved: no servo was read${notSaved}`); return; }
  download(doc, backupName(ids));
  say(`${doc.servos.length} servo(s) saved as ${backupName(ids)}${notSaved}`, lacking.length ? "error" : "info");
}

// ---- Live

const COLORS = ["#0b63c5", "#b3261e", "#1e7b34", "#8a5a00", "#6a1b9a", "#00838f", "#c2185b", "#455a64"];

async function startLive() {
  let ids;
  const text = $("#live-ids").value.trim();
  try { ids = text ? await idsIn(text) : servosHere(); } catch (e) { return; }
  if (!ids.length) { say("scan first, or name the servos to plot (e.g. 0-31)"); return; }
  state.history = []; state.liveIds = new Set();
  state.livePaused = false; $("#live-pause").textContent = "Pause";  // (a new plot: an old one's pause outlived it)
  const started = await api("/api/live/start", { ids, free_ics35: $("#live-free").checked });
  const kept = started.kept_held || [];  // (not freed: a joint of a standing robot stays up)
  const notes = [];
  if (kept.length) notes.push(kept.length > 1 ? `${servosNamed(kept)}: held by their Servo pages, so streamed their targets, not freed`
    : `${servosNamed(kept)}: held by its Servo page, so streamed its target, not freed`);
  const left = started.left_out || [];  // (ICS 3.5, not freed: "free ICS 3.5 servos" was not ticked)
  if (left.length) notes.push(`${servosNamed(left)} not plotted: ICS 3.5 reads a position only by going free (tick "free ICS 3.5 servos" to plot ${left.length > 1 ? "them" : "it"} limp)`);
  if (notes.length) say(notes.join("; "), "info");
}

// No stream runs (stopped, or none yet): its last rate and lists are not now's (they stayed, as if it ran on).
function liveStopped() {
  const cycle = $("#live-cycle");
  if (cycle.textContent !== "-" && !cycle.textContent.endsWith("(stopped)")) cycle.textContent += " (stopped)";
  for (const part of ["#live-rate", "#live-updates", "#live-offline", "#live-watched", "#live-held"]) $(part).textContent = "-";
  $("#live-held").className = "";
  state.updates = [];
}

function onLive(frame) {
  if (!frame) return;
  // The server sends these only when they change: each frame is filled in from the last ones sent.
  for (const part of ["targets", "current", "temperature", "watched", "offline", "held"]) {
    if (frame[part] === undefined) frame[part] = state.liveParts[part]; else state.liveParts[part] = frame[part];
  }
  for (const id of Object.keys(frame.positions)) state.liveIds.add(id);  // a frame lacks an ID that missed its cycle
  // The server pushes the newest frame it has: the same one again while the stream stands still (its port lost),
  // which is no update, and no rate of the stream's now.
  const now = performance.now();
  if (frame.cycle !== state.liveCycle) state.updates.push(now);
  state.liveCycle = frame.cycle;
  while (state.updates.length && now - state.updates[0] > 1000) state.updates.shift();
  const lost = !!(state.status && state.status.lost);
  $("#live-cycle").textContent = lost ? `${frame.cycle} (the port is lost: nothing read since)` : frame.cycle;
  $("#live-rate").textContent = lost ? "-" : frame.rate_hz;
  $("#live-updates").textContent = state.updates.length;
  $("#live-offline").textContent = frame.offline.length ? frame.offline.join(",") : "none";
  $("#live-watched").textContent = frame.watched.length ? frame.watched.join(",") : "none";
  // Held by the stream since their port came back ("resumed") or they answered again ("rejoined"): sent
  // nothing, their servos may have restarted, free and elsewhere; a flat line alone would not say so.
  const held = Object.entries(frame.held || {});
  $("#live-held").textContent = held.length ? held.map(([id, why]) => `${id} (held: ${why})`).join(", ") +
    ": they may have restarted, free and elsewhere; Free on a servo's page has the stream read it again" : "none";
  $("#live-held").className = held.length ? "bad" : "";
  if (state.livePaused) return;
  const last = state.history[state.history.length - 1];
  if (last && last.cycle === frame.cycle) return;
  state.history.push(frame);
  if (state.history.length > 3000) state.history.shift();
  if (!$("#page-live").hidden) drawPlot();
}

function drawPlot() {
  const canvas = $("#plot"), g = canvas.getContext("2d");
  // Drawn at the size it is shown (a phone's is a third of a laptop's), so the labels stay readable.
  const width = Math.round(canvas.clientWidth);
  if (width && canvas.width !== width) { canvas.width = width; canvas.height = Math.max(220, Math.round(width * 0.4)); }
  const what = $("#live-what").value;
  const frames = state.history.slice(-600);
  g.clearRect(0, 0, canvas.width, canvas.height);
  if (frames.length < 2) return;
  const ids = [...state.liveIds].sort((a, b) => a - b);
  // A target of 0 or -1 is the stream's mark, not a position: free, or an ICS 3.6 servo it only reads (torque
  // left alone). Drawn, a free servo's 0 squashed every other line; the legend says which in words.
  const plotted = (v) => v !== undefined && (what === "targets" ? v > 0 : v >= 0);
  const words = (v) => what !== "targets" || v === "-" || v > 0 ? v : v === 0 ? "free" : "left alone";
  const latest = (id) => { for (let i = frames.length - 1; i >= 0; i--) if (frames[i][what][id] !== undefined) return frames[i][what][id]; return "-"; };
  // The last value of a servo that stopped answering, or that the stream sends nothing, is not now's.
  const newest = frames[frames.length - 1], held = newest.held || {}, offline = new Set(newest.offline.map(String));
  const note = (id) => (offline.has(id) ? " (offline)" : "") + (held[id] ? ` (held: ${held[id]})` : "");
  const color = (k) => `color:${COLORS[k % COLORS.length]}`;
  $("#legend").replaceChildren(...ids.map((id, k) => el("span", { style: color(k), "data-id": id },
    `■ ${id}: ${words(latest(id))}${note(id)}`)));
  // (Said first: with nothing to draw, every servo free, the legend still says so.)
  let lo = Infinity, hi = -Infinity;
  for (const f of frames) for (const id of ids) { const v = f[what][id]; if (plotted(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); } }
  if (lo === Infinity) return;
  if (hi - lo < 1) { hi += 1; lo -= 1; }
  const t0 = frames[0].t, t1 = frames[frames.length - 1].t || t0 + 1;
  const x = (t) => 40 + (canvas.width - 50) * (t - t0) / Math.max(1e-9, t1 - t0);
  const y = (v) => canvas.height - 20 - (canvas.height - 30) * (v - lo) / (hi - lo);
  g.fillStyle = "#5b6570"; g.font = "12px sans-serif";
  g.fillText(String(Math.round(hi)), 2, 14); g.fillText(String(Math.round(lo)), 2, canvas.height - 22);
  ids.forEach((id, k) => {
    g.strokeStyle = COLORS[k % COLORS.length]; g.beginPath();
    let started = false;
    for (const f of frames) {
      const v = f[what][id];
      if (!plotted(v)) continue;
      if (started) g.lineTo(x(f.t), y(v)); else { g.moveTo(x(f.t), y(v)); started = true; }
    }
    g.stroke();
  });
}

function exportCsv() {
  const frames = state.history;
  if (!frames.length) { say("nothing recorded yet: start the stream first"); return; }
  const ids = [...state.liveIds].sort((a, b) => a - b);
  const head = ["t", "cycle", ...ids.flatMap((id) => [`pos_${id}`, `target_${id}`, `current_${id}`, `temp_${id}`])];
  const lines = [head.join(",")];
  // t: seconds since the first frame recorded (the frames carry the server's monotonic clock: hours, not a start).
  for (const f of frames) lines.push([(f.t - frames[0].t).toFixed(4), f.cycle, ...ids.flatMap((id) => [f.positions[id] ?? "", f.targets[id] ?? "", f.current[id] ?? "", f.temperature[id] ?? ""])].join(","));
  const link = el("a", { href: URL.createObjectURL(new Blob([lines.join("\n") + "\n"], { type: "text/csv" })), download: "ics35-live.csv" });
  document.body.append(link); link.click(); link.remove();
}

// ---- Traffic

function onTraffic(entries) {
  state.traffic.push(...entries);
  if (state.traffic.length > 2000) state.traffic.splice(0, state.traffic.length - 2000);
  if (!state.trafficPaused) drawTraffic();
}

// A time of day on the person's own clock, to the millisecond ("16:14:36.361"): what they compare with the robot.
function clockTime(seconds) {
  const d = new Date(seconds * 1000);
  const two = (n) => String(n).padStart(2, "0");
  return `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}.${String(d.getMilliseconds()).padStart(3, "0")}`;
}

function drawTraffic() {
  const filter = $("#traffic-filter").value.trim().toLowerCase();
  const rows = state.traffic.filter((e) => !filter || `${e.id} ${e.command} ${e.outcome}`.toLowerCase().includes(filter)).slice(-300).reverse();
  $("#traffic-table tbody").replaceChildren(...rows.map((e) => el("tr", {}, el("td", {}, clockTime(e.time)),
    el("td", {}, e.id ?? "-"), el("td", {}, e.command), el("td", {}, e.sent), el("td", {}, e.received || "-"), el("td", { class: e.outcome === "ok" ? "" : "bad" }, e.outcome))));
  $("#traffic-count").textContent = `${rows.length} shown of ${state.traffic.length}`;
}

// ---- Robot

function onRobot(r) {
  state.robot = r;
  $("#robot-name").textContent = r.name;
  $("#robot-error").textContent = r.error || "";
  if (state.sayingStillLost && r.reconnect_ready) say(r.reconnect_ready, "info");
  $("#robot-warnings").replaceChildren(...r.warnings.map((text) => el("li", {}, `warning: ${text}`)));
  // The lines lost (or never opened): open them again from here; when the lost line's joints were holding,
  // the person says what they do (the server cannot tell whether their servos kept their power).
  const choice = r.open ? null : r.reconnect_choice;
  // The open's question (a robot not yet open on a serial line): the ICS 3.5 joints it would free to read them.
  const freeing = r.open ? null : r.start_free_choice;
  $("#robot-reopen").hidden = r.open || Boolean(choice) || Boolean(freeing);
  $("#robot-reopen-choice").hidden = !choice;
  $("#robot-reopen-question").textContent = choice ? reconnectQuestion(choice) : "";
  $("#robot-start-free-choice").hidden = !freeing;
  $("#robot-start-free-question").textContent = freeing ? startFreeQuestion(freeing.joints) : "";
  $("#robot-motion").disabled = !r.open;
  $("#robot-cycle").textContent = r.cycle ?? "-";
  if (!state.motionAsked) $("#robot-motion").checked = r.motion_enabled;  // not over a tick the server has yet to take
  $("#robot-play").disabled = !r.motion_enabled || !$("#robot-motion-file").files.length;
  const tripped = r.joints.filter((j) => j.tripped);
  // (the watch reads an open robot's joints: of one not open, nothing is known to be within limits)
  const watch = !r.open ? "" : tripped.length ? `; SAFETY STOP: ${tripped.map((j) => j.tripped).join("; ")}` : "; safety watch: all within limits";
  $("#robot-state").textContent = (r.playing ? `playing ${r.playing}` : r.outcome || (r.open ? "idle" : "not open")) + watch;
  const body = $("#robot-table tbody");
  if (body.children.length !== r.joints.length) {
    // The slider and the angles first: on a phone the columns to the right scroll out of sight.
    body.replaceChildren(...r.joints.map((j) => el("tr", { "data-joint": j.name }, el("td", {}, j.name),
      el("td", {}, el("input", { type: "range", min: j.min, max: j.max, step: 1, value: 0, name: `joint-${j.name}`, title: `${j.min}..${j.max}°` })),
      el("td", { class: "angle" }), el("td", { class: "target" }), el("td", { class: "safety" }),
      el("td", { class: "temp" }), el("td", { class: "current" }),
      el("td", {}, el("a", { href: `#servo/${j.id}`, title: "this servo on the Servo page", onclick: (e) => { e.preventDefault(); openJoint(j.line, j.id).catch(() => {}); } }, `${j.line} / ${j.id}`)))));
    for (const slider of body.querySelectorAll("input[type=range]")) {
      const name = slider.name.slice(6);
      slider.addEventListener("change", () => moveJoint(name, +slider.value).catch(() => {
        // Refused (nothing sent): the slider goes back to where the joint is asked to be, and lets go of the
        // focus that keeps the pushed state off it while it is being moved.
        slider.blur();
        const j = state.robot.joints.find((joint) => joint.name === name);
        if (j && sliderAt(j) !== null) slider.value = sliderAt(j);
      }));
    }
  }
  for (const j of r.joints) {
    const row = body.querySelector(`tr[data-joint="${j.name}"]`);
    row.querySelector(".angle").textContent = j.offline ? "offline" : j.position ?? "-";
    // Held (sent nothing since its servo answered again, or its line came back): its old target is not where it is.
    // Its Free button: the page's way out of a hold (its servo then read where it stands, and moved from there).
    // Rebuilt only when the hold changes: a button replaced under the pointer would lose its click.
    const target = row.querySelector(".target");
    // Uncommanded (only read, its torque as found; or its servo offline): no target went out, whatever it was
    // asked ("-", as `ics35 play` shows it); another joint with none was sent its free.
    // (held with no target, as a joint silent at the open comes back: nothing was sent, it is not "free")
    // (Free all asked while its line is lost: its servo may hold until the line is back, when its free goes out)
    const free = j.free_when_back ? `free once line ${j.line} is back` : "free";
    const shown = (j.uncommanded || (j.held && j.target === null) ? "-" : j.target ?? free) + (j.held ? ` (held: ${j.held}, sent nothing)` : "");
    // (its Free button only on an open robot: a stopped one frees nothing but through Free all)
    if (target.dataset.shown !== shown + r.open) {
      target.dataset.shown = shown + r.open;
      target.replaceChildren(shown, ...(j.held && r.open ? [" ", el("button", { class: "free-joint", title: "torque off for this joint: it is read where it stands, and a move starts from there", onclick: () => freeJoint(j.name).catch(() => {}) }, "Free")] : []));
    }
    target.className = j.held ? "target bad" : "target";
    row.querySelector(".temp").textContent = j.temperature_c ?? "-";
    row.querySelector(".current").textContent = j.current ?? "-";
    // A tripped joint's Reset: the person says its cause is dealt with (a current trip of a freed joint stands
    // until then). Rebuilt only when the stop changes: a button replaced under the pointer would lose its click.
    const safety = row.querySelector(".safety");
    const stop = j.tripped || (r.open ? "" : "-");  // ("-": not watched, the robot not open)
    if (safety.dataset.stop !== stop) {
      safety.dataset.stop = stop;
      safety.replaceChildren(j.tripped || (r.open ? "ok" : "-"), ...(j.tripped ? [" ", el("button", { class: "reset-trip", title: "the cause is dealt with: targets and motions for this joint go again", onclick: () => resetTrip(j.name).catch(() => {}) }, "Reset")] : []));
    }
    safety.className = j.tripped ? "safety bad" : "safety";
    const slider = row.querySelector("input[type=range]");
    slider.disabled = !r.motion_enabled;
    if (document.activeElement !== slider && sliderAt(j) !== null) slider.value = sliderAt(j);
  }
}

// Reconnect's question, worded for one joint or several (and one line or several).
function reconnectQuestion(choice) {
  const lost = choice.lines.length === 1 ? `Line ${choice.lines[0]} was lost.` : `Lines ${choice.lines.join(", ")} were lost.`;
  const joints = choice.joints.join(", ");
  if (choice.joints.length === 1) {
    return `${lost} ${joints} had a target its servo may no longer hold (on the lost line, or held since its servo answered again). ` +
      "If its servo kept its power it still holds it; if it restarted, it is free somewhere else.";
  }
  return `${lost} ${joints} had targets their servos may no longer hold (on the lost line, or held since their servo answered again). ` +
    "If their servos kept their power they still hold them; if they restarted, they are free somewhere else.";
}

// The open's question, worded for one joint or several.
function startFreeQuestion(joints) {
  const one = joints.length === 1;
  return `${one ? "Joint" : "Joints"} ${joints.join(", ")} ${one ? "speaks" : "speak"} ICS 3.5: ${one ? "its" : "their"} position is read only by freeing ${one ? "it" : "them"}, ` +
    `and a robot standing on ${one ? "it" : "them"} falls. Hold the robot (or lay it down) first; or start the server ` +
    `again with --start-pose stating where ${one ? "it stands" : "they stand"}: ${one ? "it holds" : "they hold"} there instead.`;
}

// Where a joint's slider stands: its target; a free joint's, where it is (not the target it had before it was
// freed: it may have been turned since, and motion switched on holds it where it is).
function sliderAt(j) {
  return j.target ?? j.position;
}

// A row's own controls are a person's action as the page's buttons are (see on): the words about the last one go.
// The server gone, or started again with another token (``why``): nothing on the Robot page is live any more (its
// switch, a motion playing, the angles read). Shown as a robot stopped by a lost line is, its joints at their last
// targets, with nothing to reconnect to.
function robotGone(why = "the configurator's server is gone") {
  const joints = state.robot.joints.map((j) => ({ ...j, position: null, offline: false, temperature_c: null, current: null }));
  onRobot({ ...state.robot, open: false, cycle: null, motion_enabled: false, playing: null, reconnect_choice: null, start_free_choice: null, joints,
    error: `${why}: nothing here is read or sent (the joints keep their last commands)` });
  $("#robot-reopen").hidden = true;
}

// The server gone, or started again with another token (``why``): the pages show nothing as live any more.  The
// Servo page's motion is off (a server started again knows no switch this page ticked: a jog would be refused)
// and its servo's position is not read; the Line page's values and the live plot's rates are the last ones read.
function serverGoneHere(why) {
  if (state.robot) robotGone(why);
  $("#motion-switch").checked = false; setMotion(false);
  state.motionFor = null;
  $("#jog-position").textContent = "-";
  $("#jog-position-note").textContent = `not read now: ${why}`;
  $("#servo-table").classList.add("stale");
  liveStopped();
}

async function freeJoint(name) {
  say("");
  onRobot(await api("/api/robot/free", { joint: name }));
}

async function resetTrip(name) {
  say("");
  onRobot(await api("/api/robot/reset_trip", { joint: name }));
}

async function moveJoint(name, degrees) {
  say("");
  await api("/api/robot/move", { pose: { [name]: degrees }, duration: numberIn($("#robot-duration"), "the move time") });
}

async function playMotion() {
  const file = $("#robot-motion-file").files[0];
  let motion;
  try { motion = JSON.parse(await file.text()); } catch (e) {
    say(`${file.name} is no motion: not JSON (a motion is the .json file ics35 teach writes)`); return;
  }
  onRobot(await api("/api/robot/play", { motion, speed: numberIn($("#robot-speed"), "the speed") }));
}

// ---------------------------------------------------------------- the WebSocket

let socket = null;
// This page's name for the server, on its WebSocket and its "enable motion" (the Servo page's and the Robot
// page's): the motion it switched on goes off once its socket is gone (the tab closed or reloaded, or its network
// went), not only when it leaves the servo's page.
const PAGE = Array.from(crypto.getRandomValues(new Uint8Array(12)), (b) => b.toString(16).padStart(2, "0")).join("");

// Recording starts when the Traffic page is first opened and goes on while this page is open, so what
// other pages do can be looked at afterwards; Pause stops it (it slows a streaming line).
function socketSend() {
  if (location.hash.startsWith("#traffic")) state.trafficVisited = true;
  const wanted = !!state.trafficVisited && !state.trafficPaused;
  if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify({ traffic: wanted }));
}

function connectSocket() {
  socket = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws?page=${PAGE}`);
  socket.onopen = () => {
    state.motionSeen = 0;  // (a server started again counts from 0)
    if (state.serverGone || state.tokenRefused) {
      state.serverGone = state.tokenRefused = false;
      say("the configurator's server is back", "info");
    }
    socketSend();
  };
  socket.onmessage = (event) => {
    const u = JSON.parse(event.data);
    if (u.status) showStatus(u.status);  // sent when it changes, as the scan's progress is
    const bar = $("#scan-progress");
    if (u.progress) { bar.max = u.progress.total || 1; bar.value = u.progress.done; }
    if (u.servos) showServos(u.servos);
    if (u.live) onLive(u.live);
    if (u.traffic) onTraffic(u.traffic);
    if (u.robot) onRobot(u.robot);
  };
  socket.onclose = async () => {
    // A server that answers but refuses this page's token was started again (each start makes a new token
    // unless one is given): "gone" would send the person looking for a server that runs.
    let refused = false;
    try { refused = [401, 403].includes((await fetch("/api/status")).status); } catch (e) { /* gone */ }
    if (refused) {
      $("#line-status").textContent = "server started again: open its new address";
      if (!state.tokenRefused) say(TOKEN_REFUSED);
      // (as gone: this page cannot read or send anything; a restart quicker than the page never showed it gone)
      serverGoneHere("the configurator's server was started again with another token (open its new address)");
      state.tokenRefused = true;
      setTimeout(connectSocket, 5000);
      return;
    }
    if (state.tokenRefused) state.serverGone = false;  // (gone after running with another token: say so)
    state.tokenRefused = false;
    const gone = "the configurator's server is gone (was `ics35 web` stopped?): trying again every second";
    $("#line-status").textContent = "server gone";
    serverGoneHere("the configurator's server is gone");
    if (!state.serverGone) say(gone);  // once: the box stays until the server is back or another action
    state.serverGone = true;
    setTimeout(connectSocket, 1000);
  };
}

// ---------------------------------------------------------------- wiring

// A person's action: the words about the last one go (its error stays only until the next try).
function on(sel, event, handler) {
  $(sel).addEventListener(event, (e) => {
    if (event === "click" || event === "submit" || e.target.type === "checkbox" || e.target.type === "file") say("");
    Promise.resolve(handler(e)).catch(() => {});
  });
}

on("#connect-form", "submit", async (e) => {
  e.preventDefault();
  showServos([]); $("#scan-summary").textContent = "";  // the servos found were the line before's
  let s;
  try {
    s = await api("/api/connect", { port: $("#port-input").value, baud: +$("#baud-select").value });
  } catch (err) {
    // Refused (said by api): the line stays where it was, and so does the box, or a Scan next would scan
    // one line while the box names another.
    if (state.status) showLineInBoxes(state.status);
    throw err;
  }
  showStatus(s); showServos([]);
  say(`connected to ${s.port}`, "info");
});
on("#scan-btn", "click", scanLine);
on("#servo-load", "click", () => loadServo());
on("#plan-btn", "click", planWrite);
on("#write-btn", "click", writeEeprom);
for (const event of ["input", "change"]) $("#eeprom-table").addEventListener(event, planStale);
on("#backup-btn", "click", backupServo);
on("#restore-file", "change", planRestore);
on("#restore-id", "change", planRestore);
on("#restore-keep-baud", "change", planRestore);
on("#restore-btn", "click", restoreServo);
on("#ram-write", "click", writeRam);
on("#ram-param", "change", ramBox);
on("#free-btn", "click", () => torque("free"));
on("#hold-btn", "click", () => torque("hold"));
on("#motion-switch", "change", toggleMotion);
on("#jog-slider", "change", () => jog(+$("#jog-slider").value));
on("#jog-minus", "click", () => jog(+$("#jog-slider").value - 100));
on("#jog-plus", "click", () => jog(+$("#jog-slider").value + 100));
on("#survey-btn", "click", survey);
on("#renumber-btn", "click", renumber);
on("#many-apply", "click", applyMany);
on("#many-backup", "click", backupMany);
on("#many-ids", "input", () => { state.manyIdsTyped = true; });
on("#live-start", "click", startLive);
on("#live-stop", "click", () => api("/api/live/stop", {}));
on("#live-pause", "click", () => { state.livePaused = !state.livePaused; $("#live-pause").textContent = state.livePaused ? "Resume" : "Pause"; });
on("#live-export", "click", exportCsv);
on("#live-what", "change", drawPlot);
on("#traffic-filter", "input", drawTraffic);
on("#traffic-pause", "click", () => {
  state.trafficPaused = !state.trafficPaused;
  $("#traffic-pause").textContent = state.trafficPaused ? "Resume" : "Pause";
  socketSend();
});
on("#robot-motion", "change", async () => {
  // Until the server answers, the states it pushes still say what motion was: they leave the box alone.
  state.motionAsked += 1;
  let answer = null;
  // Named: the server switches the motion this page switched on off again once the page is gone.
  const asked = { enabled: $("#robot-motion").checked, page: PAGE };
  try { answer = await api("/api/robot/motion", asked); } catch (e) { $("#robot-motion").checked = false; }
  state.motionAsked -= 1;
  if (answer) onRobot(answer);
});
on("#robot-motion-file", "change", () => { $("#robot-play").disabled = !(state.robot && state.robot.motion_enabled); });
on("#robot-play", "click", playMotion);
on("#robot-stop", "click", async () => onRobot(await api("/api/robot/stop", {})));
on("#robot-free", "click", async () => onRobot(await api("/api/robot/free", {})));
// Pressed before the lost line is back, Reconnect is refused (409): its words give way to "back" once it is.
async function reopenRobot(data) {
  try {
    onRobot(await api("/api/robot/reopen", data));
  } catch (e) {
    if (e.status === 409) state.sayingStillLost = true;
    throw e;
  }
}

on("#robot-reopen", "click", () => reopenRobot({}));
on("#robot-reopen-hold", "click", () => reopenRobot({ lost_joints: "hold" }));
on("#robot-reopen-free", "click", () => reopenRobot({ lost_joints: "free" }));
on("#robot-start-free", "click", () => reopenRobot({ start_free: state.robot.start_free_choice.joints }));
window.addEventListener("hashchange", show);

api("/api/status").then(showStatus).catch(() => {});
loadPorts().catch(() => {});
connectSocket();
show();
positionLoop();
