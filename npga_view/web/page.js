// npga-view's page for LAM web avatars: LAM's own web player (gaussian-splat-renderer-for-lam 0.0.8, npm, MIT;
// served by the same server under player/) loads a LAM-style zip, is driven by ARKit weights and shows it.
// Everything it fetches comes from the server that serves this page.
//
// Without a zip= parameter the page asks its server (`npga-view web`) for config.json: {zip, take, live}, the
// avatar's URL and what drives it: take = URL of {fps, names, frames} (played at its rate, looped), live = URL
// of a long poll (live?after=SEQ answers {seq, weights} once a weight newer than SEQ arrived).
//
// Query parameters:
//   zip=URL            the avatar zip (the player takes the folder inside it from the zip's directory entry)
//   weights=JSON       fixed ARKit weights {"jawOpen": 0.8, ...}, as npga-view takes them (the player rescales
//                      about 20 mouth weights itself: a FRESH object is handed to it every frame, since it
//                      rescales in place)
//   camera=JSON        {"position": [x, y, z], "target": [x, y, z]}: the player's orbit controls keep the camera
//                      level with its target, so give both at the same height (default: LAM's own camera)
//   width=, height=    the view's size in CSS pixels (default 512 x 512; the window's size when served by
//                      `npga-view web`)
//   background=0xRRGGBB (default 0xffffff, the player's)
//   report=URL         where to POST the frame once it is stable: {width, height, rgba (base64, bottom row first),
//                      view, projection (column-major, three.js), fov, aspect, frames}; errors are POSTed as {error}.
//                      Driven by a take or Live Link, a frame is POSTed every `every` ms (default 1000) instead,
//                      with the weights it was drawn at ({weights, frame, seq}).
import { GaussianSplatRenderer, SceneRevealMode } from './player/gaussian-splat-renderer-for-lam.module.js';

const q = new URLSearchParams(location.search);
const json = (name, fallback) => (q.has(name) ? JSON.parse(q.get(name)) : fallback);
const weights = json('weights', {});
const camera = json('camera', null);
const served = !q.has('zip');  // by `npga-view web`: config.json says what to play
const width = Number(q.get('width') || (served ? window.innerWidth : 512));
const height = Number(q.get('height') || (served ? window.innerHeight : 512));
const report = q.get('report');
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

function post(body) {
  if (!report) return Promise.resolve();
  // a simple request (text/plain, no-cors): the receiver may be another local port
  return fetch(report, { method: 'POST', mode: 'no-cors', headers: { 'Content-Type': 'text/plain' },
                         body: JSON.stringify(body) });
}
function log(message) {
  post({ log: String(message) });
}
function fail(message) {
  document.title = 'error';
  post({ error: String(message) });
}
window.addEventListener('error', (e) => fail(e.message));
window.addEventListener('unhandledrejection', (e) => fail(e.reason && e.reason.stack ? e.reason.stack : e.reason));
const consoleError = console.error.bind(console);
console.error = (...args) => { consoleError(...args); fail(args.map(String).join(' ')); };

function base64(bytes) {
  let s = '';
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

// what drives the avatar: fixed weights, a take played at its rate (looped), or the newest Live Link weights
const drive = { given: { weights, frame: -1, seq: -1 }, take: null, live: null, seq: 0, t0: 0 };

function current() {
  if (drive.take) {
    const t = drive.take;
    const frame = Math.floor(((performance.now() - drive.t0) / 1000) * t.fps) % t.frames.length;
    const w = {};
    t.names.forEach((name, i) => { w[name] = t.frames[frame][i]; });
    return { weights: w, frame, seq: -1 };
  }
  if (drive.live) return { weights: drive.live, frame: -1, seq: drive.seq };
  return drive.given;
}

async function poll(url) {
  for (;;) {
    try {
      const r = await fetch(`${url}?after=${drive.seq}`, { cache: 'no-store' });
      const doc = await r.json();
      if (doc.seq > drive.seq) { drive.seq = doc.seq; drive.live = doc.weights; }
    } catch (e) {
      await sleep(1000);  // the server is gone or restarting: try again
    }
  }
}

async function configure() {
  if (!served) return q.get('zip');
  const config = await (await fetch('config.json', { cache: 'no-store' })).json();
  if (config.take) {
    drive.take = await (await fetch(config.take, { cache: 'no-store' })).json();
    drive.t0 = performance.now();
  }
  if (config.live) {
    drive.live = {};
    poll(config.live);
  }
  return config.zip;
}

async function main() {
  const zip = await configure();
  const div = document.getElementById('avatar');
  div.style.width = `${width}px`;
  div.style.height = `${height}px`;
  let loaded = false;
  let given = drive.given;
  const renderer = await GaussianSplatRenderer.getInstance(div, zip, {
    // a fresh object every frame: the player multiplies it by its scales in place
    getExpressionData: () => { given = current(); return { ...given.weights }; },
    backgroundColor: q.get('background') || '0xffffff',
    loadProgress: (p) => { if (p >= 1) loaded = true; },
  });
  if (!renderer || !renderer.viewer) throw new Error('the player did not load the avatar (see the console)');
  const viewer = renderer.viewer;
  viewer.sceneRevealMode = SceneRevealMode.Instant;  // no fade-in over the first frames
  log('player created');
  if (camera) {
    viewer.camera.position.fromArray(camera.position);
    if (viewer.controls) {
      viewer.controls.target.fromArray(camera.target);
      viewer.controls.update();
    } else {
      viewer.camera.lookAt(...camera.target);
    }
  }
  // read the frame back in the same task that drew it (the drawing buffer is not preserved after that)
  const gl = viewer.renderer.getContext();
  const draw = viewer.render.bind(viewer);
  let wanted = null;
  viewer.render = (...args) => {
    const out = draw(...args);
    if (wanted) {
      const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
      const rgba = new Uint8Array(w * h * 4);
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, rgba);
      const done = wanted;
      wanted = null;
      done({ rgba, w, h, drawn: given });
    }
    return out;
  };
  const grab = () => new Promise((resolve) => { wanted = resolve; viewer.forceRenderNextFrame(); });
  for (let i = 0; !loaded || !viewer.splatMesh; i++) {
    if (i % 40 === 0) log(`waiting: loaded ${loaded}, splatMesh ${!!viewer.splatMesh}`);
    await sleep(50);
  }
  log('loaded');
  document.title = 'playing';
  if (drive.take || drive.live) {
    if (report) reportEvery(grab, Number(q.get('every') || 1000));
    return;
  }
  // the splats are sorted in a worker: wait until two frames 300 ms apart are identical (at most `tries` frames)
  const tries = Number(q.get('tries') || 40);
  let last = null, frames = 0, same = false, changed = -1;
  while (frames < tries && !same) {
    await sleep(300);
    const f = await grab();
    frames += 1;
    const flat = f.rgba.every((v, i) => v === f.rgba[i % 4]);
    changed = last === null || last.rgba.length !== f.rgba.length ? -1
      : f.rgba.reduce((n, v, i) => n + (v !== last.rgba[i] ? 1 : 0), 0);
    same = !flat && changed === 0;
    log(`frame ${frames} at ${(performance.now() / 1000).toFixed(1)} s: ${flat ? 'flat' : 'drawn'}, ${changed} values changed`);
    last = f;
  }
  const cam = viewer.camera;
  cam.updateMatrixWorld(true);
  await post({ width: last.w, height: last.h, rgba: base64(last.rgba), stable: same, frames, changed,
               view: Array.from(cam.matrixWorldInverse.elements), projection: Array.from(cam.projectionMatrix.elements),
               fov: cam.fov, aspect: cam.aspect, position: cam.position.toArray() });
  document.title = 'done';
}

// driven: a frame and the weights it was drawn at, every `ms`, for as long as the page is open
async function reportEvery(grab, ms) {
  for (let n = 1; ; n++) {
    await sleep(ms);
    const f = await grab();
    await post({ width: f.w, height: f.h, rgba: base64(f.rgba), weights: f.drawn.weights, frame: f.drawn.frame,
                 seq: f.drawn.seq, n });
  }
}

main().catch((e) => fail(e && e.stack ? e.stack : e));
