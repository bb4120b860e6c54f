// eqhrl_ros advice console: shows the env and the learner's requests, sends the person's input.
// One websocket to the advice_console node (same origin); see nodes/advice_console_node.py.
'use strict';

let STEP = 0.25;            // change of the command per key press, in [-1, 1] units (the console's key_step)
const DEADZONE = 0.08;      // gamepad stick values below this read as 0
const GAMEPAD_DEADMAN = 4;  // LB on the standard mapping
const GAMEPAD_ANSWER = 0;   // A
const GAMEPAD_SKIP = 1;     // B

const $ = (id) => document.getElementById(id);
const state = { env: null, request: null, episodes: [], learner: {}, require_deadman: true, stopped: false };
const input = { command: [], deadman: false, keyDeadman: false, padDeadman: false, takeOver: false };
let socket = null;
let lastRequestKey = null;
let padButtons = [];
let budgetEdited = false;  // the person is typing a budget: the learner's value does not overwrite it
let budgetSEdited = false;
let connected = false;
let stoppingReason = '';  // the console said it is stopping: its close frame may lack the reason

function connect() {
  const url = new URL('ws', window.location.href);
  url.protocol = url.protocol === 'https:' ? 'wss:' : 'ws:';
  socket = new WebSocket(url);
  socket.binaryType = 'blob';
  socket.onopen = () => {
    connected = true;
    $('connection').textContent = 'connected'; $('connection').className = '';
    $('stop').disabled = false;
  };
  socket.onclose = (event) => {
    // Never a STOP that does nothing: without the console, the page cannot stop the robot.
    const wasConnected = connected;
    connected = false;
    $('connection').textContent = 'disconnected: reconnecting...';
    $('connection').className = 'bad';
    $('stop').disabled = true;
    $('stop').textContent = 'STOP (not connected)';
    const reason = event.reason || stoppingReason;
    stoppingReason = '';
    if (wasConnected || reason) {
      $('run-state').textContent = reason
        ? `the console has stopped (${reason}): the run has ended or was stopped; STOP cannot reach the robot from this page`
        : 'the console is not reachable: STOP cannot reach the robot from this page until it reconnects';
    }
    setTimeout(connect, 1000);
  };
  socket.onmessage = (event) => {
    if (event.data instanceof Blob) { blobs = blobs.then(() => showBlob(event.data)); return; }
    const message = JSON.parse(event.data);
    if (message.type === 'state') onState(message);
    else if (message.type === 'set_result') {
      if (message.name === 'advising_budget') budgetEdited = false;
      if (message.name === 'advising_budget_s') budgetSEdited = false;
      say(message.ok ? `${message.name} set to ${message.value}` : `refused: ${message.reason}`);
    }
    else if (message.type === 'error') say(`console: ${message.error}`);
    else if (message.type === 'stopping') stoppingReason = String(message.reason);
  };
}

function send(data) {
  if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(data));
}

function say(text) { $('message').textContent = text; }

// Text from another node (an env's labels) made safe to put into markup: shown, never parsed.
function escapeHtml(text) {
  const holder = document.createElement('span');
  holder.textContent = String(text);
  return holder.innerHTML;
}

// ------------------------------------------------------------------ what the node sends

// Images come as binary messages, each led by one byte that says which (console_server.py,
// IMAGE_KINDS): E the env's rendering (JPEG), A the frames a camera learner asked about (one PNG,
// the stack side by side), C the learner's camera live (PNG, at its size).
const IMAGE_KINDS = { E: 'frame', A: 'asked', C: 'camera' };
let blobs = Promise.resolve();  // shown in the order they came
async function showBlob(blob) {
  const kind = IMAGE_KINDS[String.fromCharCode(new Uint8Array(await blob.slice(0, 1).arrayBuffer())[0])];
  if (kind) showImage(kind, blob.slice(1));
}

function showImage(id, blob) {
  const image = $(id);
  const old = image.src;
  image.src = URL.createObjectURL(blob);
  if (old.startsWith('blob:')) URL.revokeObjectURL(old);
  image.dataset.frames = String(Number(image.dataset.frames || 0) + 1);
  if (id === 'camera' && state.camera) showCamera();  // its caption says whether a frame came
}

// The learner's frames at its own size, each pixel drawn as a square block: scaled by a whole
// number, as large as fits (at most 240 px high), never smoothed, so the person judges what it judges.
function drawnScale(image, frames, width, height) {
  const room = $('learner-views').clientWidth || 480;
  const scale = Math.max(1, Math.min(Math.floor(240 / height), Math.floor(room / (frames * width))));
  $(image).style.width = `${frames * width * scale}px`;
  return scale;
}

function showCamera() {
  const camera = state.camera;
  $('camera-view').hidden = !camera;
  if (!camera) return;
  const scale = drawnScale('camera', 1, camera.width, camera.height);
  $('camera-caption').textContent = `what the learner sees now: camera '${camera.name}' on ${camera.topic}, ` +
    `${camera.width}x${camera.height} ${camera.encoding}, drawn ${scale}x` +
    ($('camera').dataset.frames ? '' : ' (no frame yet)') + (camera.refused ? `; ${camera.refused} frames refused` : '');
}

// What the learner saw when it asked: the stack it judged, oldest left.
function showAsked() {
  const asked = state.asked_frames;
  $('asked-view').hidden = !asked;
  if (!asked) return;
  const scale = drawnScale('asked', asked.stack, asked.width, asked.height);
  $('asked-caption').textContent = `what the learner saw when it asked (episode ${asked.episode}, ` +
    `step ${asked.step}): ${asked.stack} frame${asked.stack > 1 ? 's' : ''} of ${asked.width}x${asked.height} ` +
    `${asked.encoding}${asked.stack > 1 ? ', oldest left' : ''}, as it reads them, drawn ${scale}x`;
}

function onState(message) {
  Object.assign(state, message);
  if (state.key_step) STEP = state.key_step;
  if (state.env && input.command.length !== state.env.action_low.length) {
    input.command = state.env.action_low.map(() => 0);
  }
  $('env').textContent = state.env ? `env: ${state.env.name}` : 'env: waiting for env_info';
  // The keys' legend names the action each key pair moves (command value k drives action i where axes[i] = k).
  [0, 1].forEach((k) => {
    const el = $(`key${k}`);
    if (!el || !state.env) return;
    const axes = state.teleop ? state.teleop.axes : state.env.action_low.map((_, i) => i);
    const i = axes.indexOf(k);
    el.textContent = i < 0 ? '(not mapped)' : (state.env.action_labels[i] || `action[${i}]`);
  });
  showDriver();
  showLegend();
  showRequest();
  showAsked();
  showCamera();
  showRecent();
  drawBars();
  drawPlots();
  const learner = state.learner || {};
  $('pause').textContent = learner.advice_enabled === false ? 'resume advice' : 'pause advice';
  document.body.classList.toggle('stopped', state.stopped === true);
  $('stop').textContent = state.stopped ? 'RESUME' : 'STOP';
  // Never under the person's cursor: a value written while the field has focus would land
  // between selecting its text and typing over it (and "100" + "7" would become "1007").
  if (!budgetEdited && document.activeElement !== $('budget') && learner.advising_budget !== undefined) {
    $('budget').value = learner.advising_budget;
  }
  if (!budgetSEdited && document.activeElement !== $('budget-s') && learner.advising_budget_s !== undefined) {
    $('budget-s').value = learner.advising_budget_s;
  }
  const last = state.episodes[state.episodes.length - 1];
  // Finished episodes' seconds, and those of the requests answered since (the budget runs down now).
  const spent = (last ? last.human_time_total_s : 0) + (state.person_s_open || 0);  // live: the open stretch runs
  // What is left is the learner's rule (core/algorithm/advice_window.py), as the console node computes it.
  const open = state.advice_window;
  $('person').textContent = `your time: ${spent.toFixed(1)} s over ${state.episodes.length} episodes` +
    (open && open.seconds_left !== null
      ? `; your budget ${learner.advising_budget_s.toFixed(0)} s: ${open.seconds_left.toFixed(1)} s left` : '');
}

const DRIVER_TEXT = {
  learner: 'the learner drives',
  person_asked: 'YOU DRIVE (asked): release the deadman to hand back',
  person_unasked: 'YOU DRIVE (unasked takeover): release the deadman to hand back',
};

function showDriver() {
  const driver = DRIVER_TEXT[state.driver] ? state.driver : 'learner';
  $('driver').textContent = DRIVER_TEXT[driver];
  $('driver').className = driver;
}

// The legend says what the learner's parameters do: steering away takes over only where its
// takeover_threshold is on, and a request asks for the wheel or for one answer by its protocol.
function showLegend() {
  const threshold = state.takeover_threshold;
  $('steer-away').textContent = (threshold === null || threshold === undefined) ? ''
    : threshold > 0
    ? `, or steer more than ${threshold} (in [-1, 1] units) away from the learner's action with the deadman held`
    : ' (steering away does not take over: the learner\'s takeover_threshold is 0)';
  const wheel = state.protocol === 'wheel';
  $('wheel-keys').hidden = !wheel;
  $('answer-keys').hidden = wheel;
}

function showRecent() {
  // As text, never as HTML: a declining expert's reason is another node's words.
  const recent = (state.recent || []).slice(-5).reverse();
  $('recent').replaceChildren(...recent.map((r, i) => {
    const line = document.createElement('div');
    line.textContent = (i ? '' : 'ended: ') + describeEnd(r);
    return line;
  }));
}

function describeEnd(r) {
  const took = r.human ? ` after ${r.response_time_s.toFixed(1)} s` : '';
  const given = r.given_action && r.given_action.length
    ? ` [${r.given_action.map((v) => (v >= 0 ? '+' : '') + v.toFixed(2)).join(', ')}]` : '';
  const detail = r.detail === 'episode_ended' ? ': the episode ended before an answer (not counted as yours)'
    : (r.detail === 'budget_spent' ? ': your seconds ran out' : (r.detail ? `: ${r.detail}` : ''));
  if (r.wheel && r.outcome === 'given') {
    return `episode ${r.episode}, step ${r.step}: you drove ${r.steps_driven} steps, handed back (${r.detail})${took}`;
  }
  if (r.wheel && r.outcome === 'failed' && r.detail === 'timeout') {
    return `episode ${r.episode}, step ${r.step}: not taken in time (the learner drove on)${took}`;
  }
  return `episode ${r.episode}, step ${r.step}: ${r.outcome}${given}${took}${detail}`;
}

function showRequest() {
  const box = $('request');
  const r = state.request;
  // The run's state, once advice cannot come any more: the budgets used up, or the run over.
  const learner = state.learner || {};
  const last = state.episodes[state.episodes.length - 1];
  const done = last ? last.episode + 1 : 0;  // episodes finished (the page keeps only the last 500)
  const over = learner.max_episodes > 0 && done >= learner.max_episodes;
  const open = state.advice_window;  // null until the learner's parameters are known
  const ended = over ? `the run has finished (${done} episodes): nothing more will be asked`
    : (open && !open.open ? `advice is over: ${open.why_closed}; the learner goes on alone` : '');
  $('run-state').textContent = ended;
  if (!r) { box.className = ''; box.textContent = ended || 'no request yet'; return; }
  const key = `${r.episode}/${r.step}`;
  const paused = r.detail === 'stopped' ? ' (held by STOP)' : '';
  if (r.wheel && (r.outcome === 'pending' || r.outcome === 'taken')) {
    // What is left of the request: the learner cut it to the episode and to your seconds.
    const left = Math.max(0, r.timeout_s - r.waited_s);
    box.innerHTML = r.outcome === 'pending'
      ? `THE LEARNER ASKS YOU TO TAKE THE WHEEL${paused}<br>press the deadman (Shift) and steer: episode ${r.episode}, step ${r.step}` +
        `<div id="countdown">${left.toFixed(1)} s</div><small>the robot drives on its own until you take it</small>`
      : `YOU HAVE THE WHEEL${paused}<br>` + (paused ? '' : `driving for ${r.waited_s.toFixed(1)} s, at most ${left.toFixed(1)} s left; `) +
        'release the deadman to hand back';
    box.className = 'wheel';
    box.dataset.outcome = r.outcome;
    if (key !== lastRequestKey) { alertPerson(box); lastRequestKey = key; }
    return;
  }
  if (r.outcome === 'pending') {
    // The person's window is teleop_expert's: its answer_window_s, cut to the learner's wait
    // less the margin that lets the answer arrive in time (not the learner's whole wait).
    const t = state.teleop;
    const margin = t ? t.answer_margin_s : 0.2;
    const window = Math.min(t ? t.answer_window_s : Infinity, r.timeout_s - margin);
    const left = Math.max(0, window - r.waited_s);
    box.dataset.outcome = r.outcome;
    const d = r.discrepancy === null ? 'n/a' : r.discrepancy.toFixed(3);
    const e = r.entropy === null ? 'n/a (QASAC)' : r.entropy.toFixed(3);
    box.innerHTML = `THE LEARNER ASKS FOR ADVICE<br>episode ${r.episode}, step ${r.step}` +
      `<div id="countdown">${left.toFixed(1)} s</div>` +
      `<small>D(s) = ${d} &nbsp; E(s) = ${e}</small>`;
    box.className = 'pending';
    if (key !== lastRequestKey) { alertPerson(box); lastRequestKey = key; }
  } else {
    box.className = '';
    // What was sent, as the env takes it: the person sees the value their input gave.
    box.textContent = `last request: ${describeEnd(r)}`;
    box.dataset.outcome = r.outcome;
  }
}

// One audio context for the page's tones. A browser lets a page sound only after the person's
// first gesture on it (its autoplay policy), so the context is made, or resumed, then; until
// then the page says so beside the sound box. (Before: a new context for every request, each
// left open, and silent, with a console warning, until the person had touched the page.)
let audio = null;

function unlockAudio() {
  // Only a gesture the browser counts: Shift alone (the deadman) is none, and a context made on it
  // stayed suspended, with the autoplay warning in the console; the next key or click makes it.
  if (navigator.userActivation && !navigator.userActivation.isActive) return;
  try {
    audio = audio || new (window.AudioContext || window.webkitAudioContext)();
    if (audio.state === 'suspended') audio.resume().then(showSoundState, showSoundState);
  } catch (error) { audio = null; /* no audio device: the flash remains */ }
  showSoundState();
}

function showSoundState() {
  $('sound-locked').hidden = audio !== null && audio.state === 'running';
}

['pointerdown', 'keydown'].forEach((kind) => window.addEventListener(kind, unlockAudio, { capture: true }));

function alertPerson(box) {
  box.classList.add('flash');
  setTimeout(() => box.classList.remove('flash'), 1100);
  if (!$('sound').checked || audio === null || audio.state !== 'running') return;
  const tone = audio.createOscillator();
  tone.frequency.value = 880;
  tone.connect(audio.destination);
  tone.start();
  tone.stop(audio.currentTime + 0.15);
}

function drawBars() {
  const bars = $('bars');
  if (!state.env) { bars.innerHTML = ''; return; }
  const low = state.env.action_low, high = state.env.action_high;
  const proposed = state.request && state.request.outcome === 'pending' ? state.request.proposed_action : null;
  const at = (i, value) => 100 * (value - low[i]) / ((high[i] - low[i]) || 1);
  // The command is in [-1, 1]; teleop_expert maps value axes[i] of it to action i with its
  // scales and offsets and clips to the bounds: the bar shows what would be sent.
  const t = state.teleop;
  const sent = (i) => {
    if (!t) return low[i] + (input.command[i] + 1) / 2 * (high[i] - low[i]);
    const v = (input.command[t.axes[i]] || 0) * t.scales[i] + t.offsets[i];
    return Math.max(low[i], Math.min(high[i], v));
  };
  const yours = (i) => at(i, sent(i));
  bars.innerHTML = low.map((_, i) => {
    const label = escapeHtml(state.env.action_labels[i] || `action[${i}]`);  // the env's words
    const p = proposed ? `<div class="mark proposed" style="left:${at(i, proposed[i])}%"></div>` : '';
    const value = sent(i);
    return `<div>${label} [${low[i]}, ${high[i]}]: <b data-action="${i}">${value >= 0 ? '+' : ''}${value.toFixed(2)}</b></div>` +
      `<div class="bar">` +
      `<div class="mark zero" style="left:${at(i, 0)}%"></div>${p}` +
      `<div class="mark yours" style="left:${yours(i)}%"></div></div>`;
  }).join('');
}

function drawPlots() {
  const episodes = state.episodes;
  const budget = (state.learner || {}).advising_budget;
  plot($('returns'), 'return per episode', episodes.map((e) => e.return), budget, '#2ecc71', false);
  plot($('advice'), 'advice given per episode (blue: by you), your seconds (orange)',
    episodes.map((e) => e.given), budget, '#3498db', true,
    episodes.map((e) => e.human_time_s));
  plot($('driven'), 'steps you drove per episode: asked (purple), unasked takeovers (green)',
    episodes.map((e) => e.asked_steps || 0), budget, '#9b59b6', true,
    episodes.map((e) => e.takeover_steps || 0), '#2ecc71');
}

function plot(canvas, title, values, budget, color, bars, second, secondColor) {
  const g = canvas.getContext('2d');
  const w = canvas.width, h = canvas.height, pad = 36;
  g.clearRect(0, 0, w, h);
  g.fillStyle = '#ccc';
  g.font = '14px sans-serif';
  g.fillText(title, pad, 16);
  const n = Math.max(values.length, (budget || 0) + 1, 2);
  const all = values.concat(second || []);
  let lo = Math.min(0, ...all), hi = Math.max(1, ...all);
  if (!bars && values.length) { lo = Math.min(...values); hi = Math.max(...values, lo + 1); }
  const x = (i) => pad + (w - 2 * pad) * i / (n - 1);
  const y = (v) => h - pad + (v - lo) / (hi - lo) * (2 * pad - h);
  g.strokeStyle = '#555';
  g.strokeRect(pad, pad, w - 2 * pad, h - 2 * pad);
  g.fillText(hi.toFixed(0), 2, pad + 4);
  g.fillText(lo.toFixed(0), 2, h - pad);
  if (budget !== undefined) {  // the early-advising budget ends here (Eq. 7)
    g.strokeStyle = '#e74c3c';
    g.setLineDash([6, 4]);
    g.beginPath(); g.moveTo(x(budget), pad); g.lineTo(x(budget), h - pad); g.stroke();
    g.setLineDash([]);
    g.fillStyle = '#e74c3c';
    g.fillText(`budget ${budget}`, Math.min(x(budget) + 4, w - 90), pad + 14);
  }
  g.strokeStyle = color; g.fillStyle = color;
  if (bars) {
    values.forEach((v, i) => g.fillRect(x(i) - 2, y(v), 4, y(lo) - y(v)));
  } else {
    g.beginPath();
    values.forEach((v, i) => (i ? g.lineTo(x(i), y(v)) : g.moveTo(x(i), y(v))));
    g.stroke();
  }
  if (second) {
    g.strokeStyle = secondColor || '#f39c12';
    g.beginPath();
    second.forEach((v, i) => (i ? g.lineTo(x(i), y(v)) : g.moveTo(x(i), y(v))));
    g.stroke();
  }
}

// ------------------------------------------------------------------ the person's input

function sendInput(extra) {
  input.deadman = input.keyDeadman || input.padDeadman;
  $('deadman').className = input.deadman ? 'held' : '';
  // The request on the screen, so that a press meant for it never lands on a newer one.
  const r = state.request;
  const shown = r && r.outcome === 'pending' ? [r.episode, r.step] : null;
  send(Object.assign(
    { type: 'input', command: input.command, deadman: input.deadman, take_over: input.takeOver, request: shown },
    extra || {}));
  drawBars();
}

// A press against the command's sign goes to 0 first: reversing full scale takes 1 + 1/STEP presses.
function nudge(index, sign) {
  if (index >= input.command.length) return;
  const now = input.command[index];
  const next = now * sign < 0 ? 0 : now + sign * STEP;
  input.command[index] = Math.max(-1, Math.min(1, Math.round(next * 100) / 100));
}

const KEYS = {
  ArrowLeft: [0, -1], KeyA: [0, -1], ArrowRight: [0, 1], KeyD: [0, 1],
  ArrowUp: [1, 1], KeyW: [1, 1], ArrowDown: [1, -1], KeyS: [1, -1],
};

document.addEventListener('keydown', (event) => {
  if (event.target.tagName === 'INPUT') return;
  if (event.key === 'Shift') { input.keyDeadman = true; sendInput(); return; }
  // T, held with the deadman: take over now, unasked; released, the learner drives again.
  if (event.code === 'KeyT') { if (!input.takeOver) { input.takeOver = true; sendInput(); } return; }
  if (KEYS[event.code]) { nudge(...KEYS[event.code]); sendInput(); event.preventDefault(); return; }
  if (event.code === 'Digit0' || event.code === 'Numpad0') { input.command.fill(0); sendInput(); return; }
  if (event.repeat) return;
  if (event.code === 'Enter' || event.code === 'NumpadEnter') { sendInput({ answer: true }); event.preventDefault(); }
  if (event.code === 'Escape' || event.code === 'KeyX') { sendInput({ skip: true }); event.preventDefault(); }
});
document.addEventListener('keyup', (event) => {
  if (event.key === 'Shift') { input.keyDeadman = false; sendInput(); }
  if (event.code === 'KeyT') { input.takeOver = false; sendInput(); }
});
window.addEventListener('blur', () => { input.keyDeadman = false; input.takeOver = false; sendInput(); });

// The browser's Gamepad API: any pad the browser knows, no driver on the robot's machine.
function pollGamepad() {
  const pads = navigator.getGamepads ? Array.from(navigator.getGamepads()).filter(Boolean) : [];
  const pad = pads[0];
  $('gamepad').textContent = pad ? `gamepad: ${pad.id}` : 'no gamepad';
  if (pad) {
    const pressed = pad.buttons.map((b) => Boolean(b && b.pressed));
    const edge = (i) => pressed[i] && !padButtons[i];
    let changed = pressed[GAMEPAD_DEADMAN] !== input.padDeadman;
    input.padDeadman = Boolean(pressed[GAMEPAD_DEADMAN]);
    [0, 1].forEach((axis) => {
      if (axis >= input.command.length || axis >= pad.axes.length) return;
      const raw = pad.axes[axis] * (axis === 1 ? -1 : 1);  // stick up is negative on the standard mapping
      const value = Math.abs(raw) < DEADZONE ? 0 : Math.round(raw * 100) / 100;
      if (value !== input.command[axis]) { input.command[axis] = value; changed = true; }
    });
    const extra = {};
    if (edge(GAMEPAD_ANSWER)) extra.answer = true;
    if (edge(GAMEPAD_SKIP)) extra.skip = true;
    if (changed || extra.answer || extra.skip) sendInput(extra);
    padButtons = pressed;
  }
}

// Keep the node's view of this page fresh (it stops publishing for a page gone quiet).
setInterval(() => { if (input.command.length) sendInput(); }, 300);

$('pause').addEventListener('click', () => {
  const enabled = (state.learner || {}).advice_enabled !== false;
  send({ type: 'set', name: 'advice_enabled', value: !enabled });
});
$('budget').addEventListener('input', () => { budgetEdited = true; });
$('budget-s').addEventListener('input', () => { budgetSEdited = true; });
$('set-budget-s').addEventListener('click', () => {
  const value = Number($('budget-s').value);
  if (!Number.isFinite(value) || value < 0) { say('your seconds are a number, 0 or more (0: no limit)'); return; }
  send({ type: 'set', name: 'advising_budget_s', value });
});
$('set-budget').addEventListener('click', () => {
  const value = Number($('budget').value);
  if (!Number.isInteger(value)) { say('the budget is a whole number of episodes'); return; }
  send({ type: 'set', name: 'advising_budget', value });
});

connect();
setInterval(pollGamepad, 20);

// STOP: the env nodes hold (no step) until it is released; the node publishes it latched on `stop`.
$('stop').addEventListener('click', () => send({ type: 'stop', stopped: !state.stopped }));
