// npga-view's page for LAM web avatars: LAM's own web player (gaussian-splat-renderer-for-lam 0.0.8, npm, MIT;
// served by the same server under player/) loads a LAM-style zip, is driven by given ARKit weights and shows it from
// a fixed camera. Everything it fetches comes from the server that serves this page.
//
// Query parameters:
//   zip=URL            the avatar zip (the player takes the folder inside it from the zip's directory entry)
//   weights=JSON       ARKit weights {"jawOpen": 0.8, ...}, as npga-view takes them (the player rescales about 20 mouth
//                      weights itself: a FRESH object is handed to it every frame, since it rescales in place)
//   camera=JSON        {"position": [x, y, z], "target": [x, y, z]}: the player's orbit controls keep the camera
//                      level with its target, so give both at the same height (default: LAM's own camera)
//   width=, height=    the view's size in CSS pixels (default 512 x 512)
//   background=0xRRGGBB (default 0xffffff, the player's)
//   report=URL         where to POST the frame once it is stable: {width, height, rgba (base64, bottom row first),
//                      view, projection (column-major, three.js), fov, aspect, frames}; errors are POSTed as {error}
import { GaussianSplatRenderer, SceneRevealMode } from './player/gaussian-splat-renderer-for-lam.module.js';

const q = new URLSearchParams(location.search);
const json = (name, fallback) => (q.has(name) ? JSON.parse(q.get(name)) : fallback);
const weights = json('weights', {});
const camera = json('camera', null);
const width = Number(q.get('width') || 512);
const height = Number(q.get('height') || 512);
const report = q.get('report');

function post(body) {
  if (!report) return Promise.resolve();
  return fetch(report, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
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

async function main() {
  const div = document.getElementById('avatar');
  div.style.width = `${width}px`;
  div.style.height = `${height}px`;
  let loaded = false;
  const renderer = await GaussianSplatRenderer.getInstance(div, q.get('zip'), {
    getExpressionData: () => ({ ...weights }),  // fresh every frame: the player multiplies it by its scales in place
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
      done({ rgba, w, h });
    }
    return out;
  };
  const grab = () => new Promise((resolve) => { wanted = resolve; viewer.forceRenderNextFrame(); });
  const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
  for (let i = 0; !loaded || !viewer.splatMesh; i++) {
    if (i % 40 === 0) log(`waiting: loaded ${loaded}, splatMesh ${!!viewer.splatMesh}`);
    await sleep(50);
  }
  log('loaded');
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

main().catch((e) => fail(e && e.stack ? e.stack : e));
