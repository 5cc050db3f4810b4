// The raytile coordinator's web pages: jobs (/), one job (/jobs/ID) and workers (/workers).
// Plain JavaScript, no build step, nothing loaded from anywhere but the coordinator. Data
// comes from the HTTP API (/v1/...), live changes from the server-sent events of /v1/events.
"use strict";

const TOKEN_KEY = "raytile-token";
const STATES = ["queued", "running", "done", "failed", "cancelled"];
const INTEGRATORS = ["path", "volpath", "bdpt", "sppm", "whitted", "normals", "albedo", "depth",
  "ao"];

// What the pages did, for people debugging them and for the end-to-end test.
window.raytile = { previews: [], events: 0, errors: [] };

// ---------------------------------------------------------------- small helpers

function h(tag, attrs, ...kids) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined || v === false) continue;
    if (k.startsWith("on")) el.addEventListener(k.slice(2), v);
    else if (k === "class") el.className = v;
    else el.setAttribute(k, v === true ? "" : v);
  }
  for (const kid of kids.flat()) {
    if (kid === null || kid === undefined || kid === false) continue;
    el.append(kid instanceof Node ? kid : String(kid));
  }
  return el;
}

function fmtTime(ms) {
  return ms ? new Date(ms).toLocaleString() : "—";
}

function fmtDur(ms) {
  if (ms === null || ms === undefined || !isFinite(ms) || ms < 0) return "—";
  const s = Math.round(ms / 1000);
  if (s < 60) return s + " s";
  if (s < 3600) return Math.floor(s / 60) + " min " + (s % 60) + " s";
  return Math.floor(s / 3600) + " h " + Math.floor((s % 3600) / 60) + " min";
}

function fmtAgo(ms) {
  return ms ? fmtDur(Date.now() - ms) + " ago" : "—";
}

function fmtRate(x) {
  if (!x) return "0";
  if (x >= 1e6) return (x / 1e6).toFixed(2) + " M";
  if (x >= 1e3) return (x / 1e3).toFixed(1) + " k";
  return x.toFixed(0);
}

function isFinal(state) {
  return state === "done" || state === "failed" || state === "cancelled";
}

// A job that failed or was cancelled before any tile was done has no image (the coordinator
// answers 409): nothing to preview or download.
function hasNoImage(job) {
  return (job.state === "failed" || job.state === "cancelled") && job.tasks_done === 0;
}

// Runs `fn` at most once every `ms` milliseconds (a number, or a function giving it), and once
// more after the last call.
function throttle(fn, ms) {
  const interval = typeof ms === "function" ? ms : () => ms;
  let timer = null;
  let again = false;
  let last = 0;
  return function run() {
    if (timer) {
      again = true;
      return;
    }
    const wait = Math.max(0, last + interval() - Date.now());
    timer = setTimeout(async () => {
      last = Date.now();
      again = false;
      try {
        await fn();
      } catch (e) {
        console.error(e);
        window.raytile.errors.push(String(e));
      } finally {
        timer = null;
        if (again) run();
      }
    }, wait);
  };
}

function tileKey(t) {
  return t.x0 + "," + t.y0;
}

function tileText(t) {
  return "[" + t.x0 + "," + t.x1 + ")×[" + t.y0 + "," + t.y1 + ")";
}

// ---------------------------------------------------------------- the token and the API

let tokenAsked = null;

// A token goes in an HTTP header, which carries printable ASCII only.
const TOKEN_TEXT = /^[\x20-\x7e]+$/;

function token() {
  const t = sessionStorage.getItem(TOKEN_KEY);
  return t && TOKEN_TEXT.test(t) ? t : null;
}

// Asks for the token (once for every request waiting on it) and keeps it for the browser
// session, in this tab only. It is sent in the Authorization header of every request, the
// event stream's and downloads' too (the coordinator takes it from nowhere else: a cookie
// would go with other sites' requests and to other services on the host).
// `why` says what was wrong with the token the page had, if it had one.
function askToken(why) {
  if (tokenAsked) return tokenAsked;
  tokenAsked = new Promise((resolve) => {
    const box = document.getElementById("token-box");
    const form = document.getElementById("token-form");
    const input = document.getElementById("token-input");
    document.getElementById("token-error").textContent = why || "";
    if (why) input.value = "";
    box.hidden = false;
    input.focus();
    form.onsubmit = (e) => {
      e.preventDefault();
      const t = input.value.trim();
      if (!t) return;
      if (!TOKEN_TEXT.test(t)) {
        document.getElementById("token-error").textContent =
          "A token is printable ASCII: letters, digits, spaces and punctuation.";
        return;
      }
      sessionStorage.setItem(TOKEN_KEY, t);
      box.hidden = true;
      tokenAsked = null;
      resolve();
    };
  });
  return tokenAsked;
}

class ApiError extends Error {
  constructor(status, body) {
    super((body && body.error && body.error.message) || "the coordinator answered " + status);
    this.status = status;
    this.field = body && body.error ? body.error.field : undefined;
  }
}

// The error body of a refused answer, or null when it has none.
async function errorBody(r) {
  try {
    return await r.json();
  } catch (_) {
    return null; // not JSON
  }
}

// What is wrong with the token the page sent, when `r` (with its error body `body`) refuses
// it: missing or unknown (401), or one the coordinator knows but takes only on other
// endpoints (403 naming the Authorization header: a worker token, on a farm whose workers
// have their own). Null when the token is not the trouble.
function tokenRefusal(r, body, sent) {
  if (r.status === 401) return sent ? "The coordinator refused that token." : "";
  if (r.status === 403 && body && body.error && body.error.field === "Authorization") {
    return "The coordinator refused that token here: " + body.error.message;
  }
  return null;
}

async function api(path, opts = {}) {
  for (;;) {
    const headers = Object.assign({}, opts.headers || {});
    const t = token();
    if (t) headers["Authorization"] = "Bearer " + t;
    const r = await fetch(path, Object.assign({}, opts, { headers }));
    if (r.ok) {
      if (opts.raw) return r;
      if (r.status === 204) return null;
      return r.json();
    }
    const body = r.status === 401 ? null : await errorBody(r);
    const refusal = tokenRefusal(r, body, !!t);
    if (refusal !== null) {
      await askToken(refusal);
      continue;
    }
    throw new ApiError(r.status, body);
  }
}

function postJson(path, body) {
  return api(path, {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body),
  });
}

// ---------------------------------------------------------------- live events

const listeners = new Set();
let stream = null; // the AbortController of the open event stream

function setLive(on, text) {
  const el = document.getElementById("live");
  el.className = on ? "on" : "";
  el.textContent = text;
}

function dispatch(data, lastId) {
  let ev;
  try {
    ev = JSON.parse(data);
  } catch (_) {
    return;
  }
  window.raytile.events++;
  const id = lastId ? Number(lastId) : null;
  for (const f of listeners) f(ev, id);
}

// Reads the event stream (server-sent events: `id:` and `data:` lines, an empty line ends an
// event) until it ends. Read with fetch rather than an EventSource, which cannot send the
// token's header. Returns what to show while it waits to open the stream again.
async function readEvents(signal) {
  const headers = { Accept: "text/event-stream" };
  const t = token();
  if (t) headers["Authorization"] = "Bearer " + t;
  const r = await fetch("/v1/events", { headers, signal, cache: "no-store" });
  if (!r.ok || !r.body) {
    const body = r.status === 401 ? null : await errorBody(r);
    const refusal = tokenRefusal(r, body, !!t);
    if (refusal !== null) {
      await askToken(refusal);
      return "reconnecting…";
    }
    // A refusal says why (a coordinator without a token opened by a host name, say).
    return body && body.error ? "refused: " + body.error.message : "reconnecting…";
  }
  setLive(true, "live");
  const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
  let text = "";
  let data = [];
  let lastId = null;
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return "reconnecting…";
    text += value;
    let from = 0;
    for (let nl = text.indexOf("\n"); nl >= 0; nl = text.indexOf("\n", from)) {
      let line = text.slice(from, nl);
      from = nl + 1;
      if (line.endsWith("\r")) line = line.slice(0, -1);
      if (line === "") {
        if (data.length) dispatch(data.join("\n"), lastId);
        data = [];
        continue;
      }
      if (line.startsWith(":")) continue; // a comment: the stream is alive
      const colon = line.indexOf(":");
      const name = colon < 0 ? line : line.slice(0, colon);
      let v = colon < 0 ? "" : line.slice(colon + 1);
      if (v.startsWith(" ")) v = v.slice(1);
      if (name === "data") data.push(v);
      else if (name === "id") lastId = v;
    }
    text = text.slice(from);
  }
}

// Opens the event stream, and opens it again 1.5 s after it ends or fails (each opening
// starts with a resync event).
function connectEvents() {
  if (stream) stream.abort();
  const ctl = new AbortController();
  stream = ctl;
  (async () => {
    while (!ctl.signal.aborted) {
      let shown = "reconnecting…";
      try {
        shown = await readEvents(ctl.signal);
      } catch (e) {
        if (!ctl.signal.aborted) console.error(e);
      }
      if (ctl.signal.aborted) return;
      setLive(false, shown);
      await new Promise((resolve) => setTimeout(resolve, 1500));
    }
  })();
}

// ---------------------------------------------------------------- job actions

function jobRequest(job) {
  const s = job.settings;
  const req = { scene: job.scene, priority: job.priority };
  for (const k of ["width", "height", "spp", "max_depth", "integrator", "seed", "camera",
                   "filter", "tile_size", "passes", "default_light", "environment",
                   "environment_rotation", "environment_strength", "alpha"]) {
    if (s[k] !== null && s[k] !== undefined) req[k] = s[k];
  }
  return req;
}

// Runs a button's action; when it fails, says why and runs `refresh` (the job may have
// changed or gone meanwhile, in another tab or by another user).
async function act(button, refresh, what) {
  button.disabled = true;
  try {
    await what();
  } catch (e) {
    alert(e.message);
    refresh();
  } finally {
    button.disabled = false;
  }
}

function jobActions(job, onChange) {
  const id = job.id;
  const out = [];
  if (!isFinal(job.state)) {
    out.push(h("button", {
      type: "button", class: "cancel", "aria-label": "Cancel job " + id,
      onclick: (e) => act(e.target, onChange, async () => {
        await api("/v1/jobs/" + encodeURIComponent(id), { method: "DELETE" });
        onChange();
      }),
    }, "Cancel"));
  }
  if (job.state === "failed" || job.state === "cancelled") {
    out.push(h("button", {
      type: "button", "aria-label": "Retry job " + id + " with the tiles it has",
      title: "Go on with the tiles it has: its failed tiles are rendered again",
      onclick: (e) => act(e.target, onChange, async () => {
        await api("/v1/jobs/" + encodeURIComponent(id) + "/retry", { method: "POST" });
        onChange();
      }),
    }, "Retry"));
  }
  out.push(h("button", {
    type: "button", "aria-label": "Raise the priority of job " + id, title: "Raise priority",
    onclick: (e) => act(e.target, onChange, async () => {
      await postJson("/v1/jobs/" + encodeURIComponent(id) + "/priority", { priority: job.priority + 1 });
      onChange();
    }),
  }, "▲"));
  out.push(h("button", {
    type: "button", "aria-label": "Lower the priority of job " + id, title: "Lower priority",
    onclick: (e) => act(e.target, onChange, async () => {
      await postJson("/v1/jobs/" + encodeURIComponent(id) + "/priority", { priority: job.priority - 1 });
      onChange();
    }),
  }, "▼"));
  out.push(h("button", {
    type: "button", "aria-label": "Submit job " + id + " again with the same settings",
    onclick: (e) => act(e.target, onChange, async () => {
      const created = await postJson("/v1/jobs", jobRequest(job));
      location.assign("/jobs/" + encodeURIComponent(created.id));
    }),
  }, "Re-submit"));
  out.push(h("button", {
    type: "button", class: "danger", "aria-label": "Delete job " + id,
    onclick: (e) => act(e.target, onChange, async () => {
      if (!confirm("Delete job " + id + " and its rendered tiles? This cannot be undone.")) return;
      await api("/v1/jobs/" + encodeURIComponent(id) + "?purge=true", { method: "DELETE" });
      onChange(true);
    }),
  }, "Delete"));
  return h("div", { class: "actions" }, out);
}

// A download link of a coordinator with a token: fetched with the token's header (a link
// cannot send it), then saved from memory.
async function download(e) {
  if (!token()) return; // the link works as it is
  e.preventDefault();
  const link = e.currentTarget;
  try {
    const r = await api(link.getAttribute("href"), { raw: true });
    const url = URL.createObjectURL(await r.blob());
    const save = h("a", { href: url, download: link.getAttribute("download"), hidden: true });
    document.body.append(save);
    save.click();
    save.remove();
    setTimeout(() => URL.revokeObjectURL(url), 60000);
  } catch (err) {
    alert(err.message);
  }
}

function progressCell(job) {
  return [
    h("progress", { max: job.tasks_total || 1, value: job.tasks_done,
      "aria-label": "Tasks done of job " + job.id }),
    h("span", { class: "progress-text" },
      job.tiles_done + "/" + job.tiles_total + " tiles · pass " + job.passes_done + "/" + job.passes),
  ];
}

function timing(job) {
  const start = job.started_ms;
  const end = job.finished_ms || Date.now();
  const elapsed = start ? end - start : null;
  let eta = null;
  if (job.state === "running" && job.samples_done > 0 && elapsed !== null) {
    eta = (elapsed * (job.samples_total - job.samples_done)) / job.samples_done;
  } else if (job.state === "done") {
    eta = 0;
  }
  return { elapsed, eta };
}

// A list read from the API (`GET path`, its field `key`), kept for a page's table:
// `refresh()` (throttled to one read every `ms`) reads it again and calls `render`. Until it
// first loads, `empty(what)` says it is loading, or why it failed (it is read again after
// 3 s: on an idle farm no event would ask for it), rather than that there is nothing.
function apiList(path, key, ms, render) {
  const list = { items: [], loaded: false, error: null };
  list.refresh = throttle(async () => {
    try {
      list.items = (await api(path))[key];
      list.loaded = true;
      list.error = null;
    } catch (e) {
      list.error = e.message;
      setTimeout(list.refresh, 3000);
      throw e;
    } finally {
      render();
    }
  }, ms);
  list.empty = (what) => list.error ? "Could not load the " + what + ": " + list.error
    : "Loading the " + what + "…";
  return list;
}

// ---------------------------------------------------------------- jobs page

function field(name, label, input) {
  input.id = "f-" + name;
  input.name = name;
  input.setAttribute("aria-describedby", "err-" + name);
  return h("div", { class: "field" + (name === "scene" ? " wide" : "") },
    h("label", { for: input.id }, label), input,
    h("span", { class: "error", id: "err-" + name, role: "alert" }));
}

// ---------------------------------------------------------------- folder upload

/** The path of each file of a folder the user chose, relative to the folder's parent. */
const relPath = (f) => f.webkitRelativePath || f.name;

/** The scene file of a chosen folder: the one .gltf, .glb or .json nearest its top. */
function folderEntry(files) {
  const scenes = files.map(relPath).filter((p) => /\.(gltf|glb|json)$/i.test(p));
  if (scenes.length === 0) throw new Error("The folder holds no .gltf, .glb or .json scene.");
  const depth = (p) => p.split("/").length;
  const top = Math.min(...scenes.map(depth));
  const nearest = scenes.filter((p) => depth(p) === top);
  if (nearest.length > 1) {
    throw new Error("The folder holds several scenes at its top (" + nearest.join(", ") +
      "): choose the scene file, or an archive.");
  }
  return nearest[0];
}

/** A POSIX ustar archive of `files` (regular files, by their relative paths), as a Blob. */
function tarOf(files) {
  const enc = new TextEncoder();
  const parts = [];
  const put = (block, at, text) => block.set(enc.encode(text), at);
  const octal = (n, width) => n.toString(8).padStart(width - 1, "0") + "\0";
  for (const f of files) {
    const path = enc.encode(relPath(f));
    // ustar names are at most 100 bytes, with up to 155 more in the prefix, cut at a '/'.
    let cut = -1;
    if (path.length > 100) {
      for (let i = 0; i < path.length && i <= 155; i++) {
        if (path[i] === 0x2f && path.length - i - 1 <= 100) { cut = i; break; }
      }
      if (cut < 0) throw new Error("A path in the folder is too long for a tar: " + relPath(f));
    }
    const block = new Uint8Array(512);
    block.set(cut < 0 ? path : path.subarray(cut + 1), 0);
    if (cut >= 0) block.set(path.subarray(0, cut), 345);
    put(block, 100, "0000644\0");
    put(block, 108, "0000000\0");
    put(block, 116, "0000000\0");
    put(block, 124, octal(f.size, 12));
    put(block, 136, octal(Math.floor((f.lastModified || 0) / 1000), 12));
    put(block, 148, "        ");
    block[156] = 0x30; // '0': a regular file
    put(block, 257, "ustar\0");
    put(block, 263, "00");
    const sum = block.reduce((a, b) => a + b, 0);
    put(block, 148, sum.toString(8).padStart(6, "0") + "\0 ");
    parts.push(block, f);
    const pad = (512 - (f.size % 512)) % 512;
    if (pad) parts.push(new Uint8Array(pad));
  }
  parts.push(new Uint8Array(1024));
  return new Blob(parts, { type: "application/x-tar" });
}

function submitForm() {
  const num = (name, placeholder) =>
    h("input", { type: "number", inputmode: "numeric", step: "1", placeholder });
  const integrator = h("select", {},
    h("option", { value: "" }, "scene's own"), INTEGRATORS.map((i) => h("option", { value: i }, i)));
  const form = h("form", { class: "submit", id: "submit-form", novalidate: true },
    field("scene", "Scene (.gltf, .glb, .json, or a .zip/.tar of a scene folder)",
      h("input", { type: "file", accept: ".gltf,.glb,.json,.zip,.tar" })),
    field("folder", "…or a scene folder (packed here as a tar)",
      h("input", { type: "file", webkitdirectory: true, multiple: true })),
    field("width", "Width", num("width", "scene's")),
    field("height", "Height", num("height", "scene's")),
    field("spp", "Samples per pixel", num("spp", "scene's")),
    field("passes", "Passes", num("passes", "scene's")),
    field("integrator", "Integrator", integrator),
    field("seed", "Seed", num("seed", "scene's")),
    field("environment", "Environment (none, R,G,B, or a .hdr/.exr in the scene's folder)",
      h("input", { type: "text", placeholder: "scene's own", autocomplete: "off" })),
    field("environment_strength", "Environment strength",
      h("input", { type: "number", step: "any", placeholder: "1" })),
    field("environment_rotation", "Environment rotation (°)",
      h("input", { type: "number", step: "any", placeholder: "0" })),
    field("priority", "Priority", num("priority", "0")),
    field("alpha", "Transparent background (alpha channel)",
      h("select", {}, h("option", { value: "" }, "scene's own"),
        h("option", { value: "true" }, "yes"), h("option", { value: "false" }, "no"))),
    h("div", { class: "buttons" },
      h("button", { type: "submit", id: "submit-button" }, "Submit"),
      h("span", { class: "error", id: "err-form", role: "alert" }),
      h("span", { class: "muted", id: "submit-status", role: "status" })));
  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    for (const el of form.querySelectorAll(".error")) el.textContent = "";
    const status = form.querySelector("#submit-status");
    const show = (fieldName, message) => {
      const el = form.querySelector("#err-" + fieldName) || form.querySelector("#err-form");
      el.textContent = message;
    };
    // A number field with text the browser cannot read as a number reads as empty: say so,
    // rather than submit the scene's own value in its place.
    const unread = [...form.querySelectorAll("input[type=number]")].filter((el) => el.validity.badInput);
    if (unread.length) {
      for (const el of unread) show(el.name, "Not a number.");
      unread[0].focus();
      return;
    }
    const file = form.elements.scene.files[0];
    const folder = [...form.elements.folder.files];
    if (!file && folder.length === 0) {
      show("scene", "Choose a scene file or a folder.");
      return;
    }
    let body, query, uploadField;
    if (file) {
      const ext = file.name.toLowerCase().split(".").pop();
      body = file;
      query = ["gltf", "glb", "json", "zip", "tar"].includes(ext) ? "?format=" + ext : "";
      uploadField = "scene";
    } else {
      try {
        const entry = folderEntry(folder);
        body = tarOf(folder);
        query = "?format=tar&entry=" + encodeURIComponent(entry);
      } catch (err) {
        show("folder", err.message);
        return;
      }
      uploadField = "folder";
    }
    const button = form.querySelector("#submit-button");
    button.disabled = true;
    try {
      status.textContent = "uploading " + (file ? file.name : folder.length + " files (" + Math.ceil(body.size / 1024) + " KiB)") + "…";
      let scene;
      try {
        scene = await api("/v1/scenes" + query, {
          method: "POST", headers: { "Content-Type": "application/octet-stream" }, body,
        });
      } catch (err) {
        show(uploadField, err.message);
        return;
      }
      const req = { scene: scene.id };
      for (const name of ["width", "height", "spp", "passes", "seed", "priority",
                          "environment_strength", "environment_rotation"]) {
        const v = form.elements[name].value.trim();
        if (v !== "") req[name] = Number(v);
      }
      if (form.elements.integrator.value) req.integrator = form.elements.integrator.value;
      if (form.elements.alpha.value) req.alpha = form.elements.alpha.value === "true";
      const environment = form.elements.environment.value.trim();
      if (environment !== "") req.environment = environment;
      status.textContent = "submitting…";
      try {
        const job = await postJson("/v1/jobs", req);
        location.assign("/jobs/" + encodeURIComponent(job.id));
      } catch (err) {
        show(err.field === "scene" ? "scene" : err.field || "form", err.message);
      }
    } finally {
      status.textContent = "";
      button.disabled = false;
    }
  });
  return form;
}

function jobsPage(main) {
  document.title = "Jobs · raytile";
  const params = new URLSearchParams(location.search);
  const filter = h("select", { id: "state-filter" },
    h("option", { value: "" }, "all"), STATES.map((s) => h("option", { value: s }, s)));
  filter.value = params.get("state") || "";
  const body = h("tbody", { id: "jobs-body" });
  const list = apiList("/v1/jobs", "jobs", 500, () => render());
  // Each job's row is kept and its cells updated in place (the link and the buttons only when
  // they change), so that a focused button or link and a click in progress survive updates.
  const rows = new Map();
  const classes = ["", "", "", "num", "num opt", "opt", "num", "opt", "num opt", "num opt", ""];
  const rowOf = (j) => {
    let r = rows.get(j.id);
    if (!r) {
      const tds = classes.map((c) => h("td", { class: c || null }));
      tds[0].append(h("a", { href: "/jobs/" + encodeURIComponent(j.id) }, j.id));
      r = { tr: h("tr", { "data-job": j.id }, tds), tds, actions: null };
      rows.set(j.id, r);
    }
    return r;
  };
  const render = () => {
    const jobs = list.items;
    const shown = jobs.filter((j) => !filter.value || j.state === filter.value).reverse();
    const ids = new Set(jobs.map((j) => j.id));
    for (const id of rows.keys()) if (!ids.has(id)) rows.delete(id);
    const trs = shown.map((j) => {
      const r = rowOf(j);
      const c = r.tds;
      const t = timing(j);
      const s = j.settings;
      c[1].replaceChildren(h("span", { class: "state state-" + j.state }, j.state));
      c[2].replaceChildren(...progressCell(j));
      c[3].textContent = s.spp;
      c[4].textContent = s.width + "×" + s.height;
      c[5].textContent = s.integrator;
      c[6].textContent = j.priority;
      c[7].textContent = fmtTime(j.created_ms);
      c[8].textContent = fmtDur(t.elapsed);
      c[9].textContent = isFinal(j.state) && j.state !== "done" ? "—" : fmtDur(t.eta);
      const actions = j.state + " " + j.priority;
      if (r.actions !== actions) {
        r.actions = actions;
        c[10].replaceChildren(jobActions(j, refresh));
      }
      return r.tr;
    });
    if (!shown.length) {
      const empty = !list.loaded ? list.empty("jobs")
        : jobs.length ? "No job is " + filter.value + "." : "No jobs yet: submit one above.";
      body.replaceChildren(h("tr", {}, h("td", { colspan: 11, class: "muted" }, empty)));
    } else if (trs.length !== body.children.length || trs.some((tr, i) => body.children[i] !== tr)) {
      body.replaceChildren(...trs);
    }
  };
  const refresh = list.refresh;
  filter.addEventListener("change", () => {
    const u = new URL(location.href);
    if (filter.value) u.searchParams.set("state", filter.value);
    else u.searchParams.delete("state");
    history.replaceState(null, "", u);
    render();
  });
  main.append(
    h("h1", {}, "Jobs"),
    h("h2", {}, "Submit a scene"),
    submitForm(),
    h("h2", {}, "Jobs"),
    h("div", { class: "filter" }, h("label", { for: "state-filter" }, "Show"), filter),
    h("div", { class: "table-wrap" }, h("table", { id: "jobs" },
      h("thead", {}, h("tr", {},
        ["Job", "State", "Progress", "spp", "Resolution", "Integrator", "Priority", "Submitted",
          "Elapsed", "ETA", "Actions"].map((c, i) =>
          h("th", { scope: "col", class: [4, 5, 7, 8, 9].includes(i) ? "opt" : null }, c)))),
      body)));
  // A task's result moves its job's counts, which the event carries: they are shown at once,
  // and the whole list (samples for the ETAs) read again at most every 5 s for them, so that
  // a busy farm with many jobs does not have every page read the list twice a second.
  const slowRefresh = throttle(refresh, 5000);
  listeners.add((ev) => {
    const job = ev.type === "job_progress" && list.items.find((j) => j.id === ev.job);
    if (job) {
      for (const k of ["tiles_done", "tiles_total", "passes_done", "passes", "tasks_done",
                       "tasks_total"]) {
        if (ev[k] !== undefined) job[k] = ev[k];
      }
      render();
      slowRefresh();
    } else if (ev.type === "resync" || ev.type.startsWith("job_")) {
      refresh();
    }
  });
  refresh();
  // Elapsed times and ETAs move on without events.
  setInterval(render, 1000);
}

// ---------------------------------------------------------------- job page

function jobPage(main, id) {
  document.title = "Job " + id + " · raytile";
  const enc = encodeURIComponent(id);
  let job = null;
  let workerNames = {};
  let tiles = new Map();
  let gone = false;
  const title = h("h1", {}, "Job " + id + " ", h("span", { id: "job-state", class: "state" }));
  const actions = h("div", { id: "job-actions" });
  const canvas = h("canvas", { id: "preview", width: 1, height: 1,
    "aria-label": "The frame so far" , role: "img" });
  const overlay = h("canvas", { class: "overlay", id: "overlay", width: 1, height: 1,
    "aria-hidden": "true" });
  const progress = h("div", { id: "job-progress" });
  const settings = h("dl", { class: "settings", id: "job-settings" });
  const shares = h("tbody", { id: "job-workers" });
  const failures = h("ul", { class: "failures", id: "job-failures" });
  const errorBox = h("p", { class: "error", id: "job-error", role: "alert" });
  const showOverlay = h("input", { type: "checkbox", id: "show-overlay", checked: true });
  const preview = h("div", { class: "preview" }, canvas, overlay);
  main.append(
    h("p", {}, h("a", { href: "/" }, "← all jobs")),
    title, actions, errorBox,
    h("div", { class: "job-layout" },
      h("section", { "aria-label": "Preview" },
        preview,
        h("div", { class: "legend" },
          h("label", {}, showOverlay, " tile overlay"),
          h("span", {}, h("span", { class: "swatch waiting" }), "no pass yet"),
          h("span", {}, h("span", { class: "swatch leased" }), "rendering (worker)"),
          h("span", {}, h("span", { class: "swatch done" }), "refining")),
        h("div", { class: "downloads", id: "job-downloads" }, "Download:",
          ["png", "exr", "hdr"].map((f) => h("a", { class: "button", href: "/v1/jobs/" + enc +
            "/image?format=" + f, download: id + "." + f, onclick: download }, f.toUpperCase())))),
      h("section", { "aria-label": "Details" },
        h("h2", {}, "Progress"), progress,
        h("h2", {}, "Settings"), settings,
        h("h2", {}, "Workers"),
        h("table", {}, h("thead", {}, h("tr", {}, h("th", {}, "Worker"),
          h("th", {}, "Tasks"), h("th", {}, "Samples"), h("th", {}, "Share"))), shares),
        h("h2", {}, "Failures"), failures)));

  const name = (w) => workerNames[w] || w;

  const renderJob = () => {
    if (!job) return;
    const st = document.getElementById("job-state");
    st.className = "state state-" + job.state;
    st.textContent = job.state;
    const shownActions = job.state + " " + job.priority;
    if (actions.dataset.shown !== shownActions) {
      actions.dataset.shown = shownActions;
      actions.replaceChildren(jobActions(job, () => refreshJob()));
    }
    errorBox.textContent = job.error || "";
    document.getElementById("job-downloads").hidden = hasNoImage(job);
    const t = timing(job);
    progress.replaceChildren(...progressCell(job),
      h("p", { class: "muted" }, "Submitted " + fmtTime(job.created_ms) + " · elapsed " +
        fmtDur(t.elapsed) + (job.state === "running" ? " · ETA " + fmtDur(t.eta) : "")));
    const s = job.settings;
    const rows = [["Scene", job.scene], ["Resolution", s.width + "×" + s.height],
      ["Samples per pixel", s.spp], ["Passes", s.passes], ["Integrator", s.integrator],
      ["Max depth", s.max_depth], ["Seed", s.seed], ["Camera", s.camera || "first"],
      ["Environment", s.environment ? s.environment + " ×" + s.environment_strength + ", " + s.environment_rotation + "°" : "scene's own"],
      ["Filter", s.filter], ["Tile size", s.tile_size], ["Default light", s.default_light],
      ["Alpha", s.alpha ? "yes (transparent background)" : "no"],
      ["Priority", job.priority]];
    settings.replaceChildren(...rows.flatMap(([k, v]) => [h("dt", {}, k), h("dd", {}, String(v))]));
    const total = job.samples_done || 1;
    const ws = Object.entries(job.workers || {});
    shares.replaceChildren(...ws.map(([w, sh]) => h("tr", {},
      h("td", {}, name(w)), h("td", { class: "num" }, sh.tasks),
      h("td", { class: "num" }, sh.samples), h("td", { class: "num" },
        ((100 * sh.samples) / total).toFixed(1) + " %"))));
    if (!ws.length) shares.append(h("tr", {}, h("td", { colspan: 4, class: "muted" }, "none yet")));
    const fs = job.failures || [];
    failures.replaceChildren(...fs.map((f) => h("li", {}, fmtTime(f.at_ms) + " · " + name(f.worker) +
      " · tile " + tileText(f.tile) + " pass " + f.pass + ": " + f.error)));
    if (!fs.length) failures.append(h("li", { class: "muted" }, "none"));
  };

  // The overlay is drawn larger than the frame so that worker names are legible.
  let scale = 1;
  // Drawn at most every 100 ms however many task events arrive (a job may have many
  // thousands of tiles): the waiting tiles are dimmed in one path, the few being rendered
  // outlined and named.
  const paintOverlay = () => {
    if (!job) return;
    const ctx = overlay.getContext("2d");
    ctx.clearRect(0, 0, overlay.width, overlay.height);
    if (!showOverlay.checked) return;
    const dim = !isFinal(job.state);
    const leased = [];
    ctx.beginPath();
    for (const t of tiles.values()) {
      if (t.workers.size) leased.push(t);
      else if (dim && t.passes_done === 0) {
        ctx.rect(t.tile.x0 * scale, t.tile.y0 * scale, (t.tile.x1 - t.tile.x0) * scale,
          (t.tile.y1 - t.tile.y0) * scale);
      }
    }
    ctx.fillStyle = "rgba(0,0,0,0.5)";
    ctx.fill();
    ctx.font = Math.max(10, Math.round(11 * scale / 2)) + "px sans-serif";
    ctx.textBaseline = "top";
    ctx.strokeStyle = "#ffb300";
    ctx.fillStyle = "#ffb300";
    ctx.lineWidth = Math.max(2, scale);
    for (const t of leased) {
      const x = t.tile.x0 * scale, y = t.tile.y0 * scale;
      const w = (t.tile.x1 - t.tile.x0) * scale, hgt = (t.tile.y1 - t.tile.y0) * scale;
      ctx.strokeRect(x + 1, y + 1, w - 2, hgt - 2);
      ctx.fillText([...t.workers].map(name).join(", "), x + 3 + ctx.lineWidth, y + 3 + ctx.lineWidth, w - 8);
    }
  };
  const drawOverlay = throttle(paintOverlay, 100);
  showOverlay.addEventListener("change", drawOverlay);

  const sizeCanvases = () => {
    const s = job.settings;
    if (canvas.width !== s.width || canvas.height !== s.height) {
      canvas.width = s.width;
      canvas.height = s.height;
      scale = Math.max(1, Math.min(8, Math.ceil(640 / Math.max(s.width, s.height))));
      overlay.width = s.width * scale;
      overlay.height = s.height * scale;
    }
  };

  // The coordinator builds the whole frame for each preview: asked for no more often than
  // every 400 ms, nor than four times as long as the last one took.
  let previewMs = 0;
  // Whether a preview was asked for after the job was known to be finished: its frame is
  // final. One asked for earlier may have been taken while `job` still held an answer that
  // predates the last result.
  let finalShown = false;
  // A finished job sends no more events: a preview of it that failed (a busy coordinator, a
  // network fault) is asked for again, a few times.
  let finalRetries = 0;
  const refreshPreview = throttle(async () => {
    if (!job || gone || hasNoImage(job)) return;
    try {
      await showPreview();
    } catch (e) {
      if (isFinal(job.state) && !finalShown && finalRetries++ < 5) {
        setTimeout(refreshPreview, 2000);
      }
      throw e;
    }
  }, () => Math.max(400, 4 * previewMs));
  const showPreview = async () => {
    const began = performance.now();
    const before = { tasks_done: job.tasks_done, tasks_total: job.tasks_total, state: job.state };
    const r = await api("/v1/jobs/" + enc + "/image?format=png", { raw: true });
    const bitmap = await createImageBitmap(await r.blob());
    sizeCanvases();
    const ctx = canvas.getContext("2d");
    // A frame with an alpha channel shows over a checkerboard; each preview replaces the last.
    preview.classList.toggle("alpha", Boolean(job.settings && job.settings.alpha));
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    ctx.drawImage(bitmap, 0, 0);
    // How much of the frame shows something (not black), for the record.
    const px = ctx.getImageData(0, 0, canvas.width, canvas.height).data;
    let lit = 0;
    for (let i = 0; i < px.length; i += 4) {
      if (px[i] > 8 || px[i + 1] > 8 || px[i + 2] > 8) lit++;
    }
    before.lit = lit / (px.length / 4);
    window.raytile.previews.push(before);
    if (isFinal(before.state)) finalShown = true;
    previewMs = performance.now() - began;
  };

  // Task events that arrive while the tile list is being fetched are kept, and those the
  // list does not include yet (a larger id than its event_id) are applied to it after.
  let pending = null;
  const refreshTiles = async () => {
    if (pending) return;
    pending = [];
    try {
      const list = await api("/v1/jobs/" + enc + "/tiles");
      tiles = new Map(list.tiles.map((t) => [tileKey(t.tile),
        { tile: t.tile, passes_done: t.passes_done, workers: new Set(t.workers) }]));
      for (const [ev, id] of pending) {
        if (id !== null && id > list.event_id) applyTask(ev);
      }
    } finally {
      pending = null;
    }
    drawOverlay();
  };

  // A job deleted meanwhile is shown as gone by refreshJob: its tile list's 404 is no error.
  const unlessGone = (e) => {
    if (e.status !== 404) console.error(e);
  };

  // A task event on the overlay's tiles.
  const applyTask = (ev) => {
    const t = tiles.get(tileKey(ev.tile));
    if (!t) return;
    if (ev.type === "task_leased") t.workers.add(ev.worker);
    else if (ev.type === "task_done") {
      t.passes_done++;
      t.workers.delete(ev.worker);
    } else {
      // A stored result lost is a pass of the tile to render again.
      if (ev.type === "task_queued" && ev.reason === "lost") {
        t.passes_done = Math.max(0, t.passes_done - 1);
      }
      t.workers.clear();
    }
  };

  const refreshWorkers = async () => {
    const list = await api("/v1/workers");
    workerNames = Object.fromEntries(list.workers.map((w) => [w.id, w.name]));
  };

  const refreshJob = throttle(async () => {
    const first = job === null;
    try {
      job = await api("/v1/jobs/" + enc);
    } catch (e) {
      if (e.status === 404) {
        gone = true;
        main.replaceChildren(h("h1", {}, "Job " + id), h("p", {}, "There is no job " + id +
          " (it may have been deleted). "), h("p", {}, h("a", { href: "/" }, "All jobs")));
        return;
      }
      if (first) errorBox.textContent = "Could not load the job: " + e.message;
      throw e;
    }
    window.raytile.job = job;
    sizeCanvases();
    renderJob();
    drawOverlay();
    // The first preview waits for the job (a finished job sends no event that would ask
    // for one later). A job seen finished for the first time is shown once more: the
    // preview its last events asked for may have been taken with `job` still out of date
    // (an answer to a read that began before the last result came in).
    if (!isFinal(job.state)) finalShown = false;
    else if (!finalShown) refreshPreview();
    if (first) refreshPreview();
  }, 300);

  listeners.add((ev, eventId) => {
    if (ev.type === "resync") {
      refreshJob();
      refreshTiles().catch(unlessGone);
      refreshPreview();
      return;
    }
    if (ev.type === "worker_registered") workerNames[ev.worker] = ev.name;
    if (ev.job !== id) return;
    if (ev.type.startsWith("task_")) {
      if (pending) pending.push([ev, eventId]);
      else applyTask(ev);
      drawOverlay();
      if (ev.type === "task_failed") refreshJob();
      return;
    }
    if (!job) return;
    switch (ev.type) {
      case "job_progress":
        Object.assign(job, {
          tiles_done: ev.tiles_done, passes_done: ev.passes_done, tasks_done: ev.tasks_done,
        });
        refreshJob();
        refreshPreview();
        break;
      case "job_purged":
        gone = false;
        refreshJob();
        break;
      default:
        refreshJob();
        if (ev.type === "job_state" && isFinal(ev.state)) {
          refreshTiles().catch(unlessGone);
          refreshPreview();
        }
    }
  });

  (async () => {
    await refreshWorkers().catch(console.error);
    refreshJob();
    await refreshTiles().catch(unlessGone);
    refreshPreview();
  })();
}

// ---------------------------------------------------------------- workers page

function workersPage(main) {
  document.title = "Workers · raytile";
  const body = h("tbody", { id: "workers-body" });
  const list = apiList("/v1/workers", "workers", 1000, () => render());
  // Rows are kept and their cells updated in place; the current-task links only when the
  // task changes (a focused link survives the refresh).
  const rows = new Map();
  const classes = ["", "", "", "num", "num", "num opt", "num opt", "num", ""];
  const render = () => {
    const workers = list.items;
    const ids = new Set(workers.map((w) => w.id));
    for (const id of rows.keys()) if (!ids.has(id)) rows.delete(id);
    const trs = workers.map((w) => {
      let r = rows.get(w.id);
      if (!r) {
        const tds = classes.map((c) => h("td", { class: c || null }));
        tds[0].append(w.name, h("span", { class: "muted" }, " " + w.id));
        r = { tr: h("tr", { "data-worker": w.id }, tds), tds, current: null };
        rows.set(w.id, r);
      }
      const c = r.tds;
      c[1].replaceChildren(h("span", { class: "state state-" + w.state }, w.state));
      const current = JSON.stringify(w.current);
      if (r.current !== current) {
        r.current = current;
        c[2].replaceChildren(...(w.current.length ? w.current.flatMap((t, i) => [i ? ", " : "",
          h("a", { href: "/jobs/" + encodeURIComponent(t.job) }, t.job),
          " tile " + tileText(t.tile) + " pass " + t.pass]) : ["—"]));
      }
      c[3].textContent = w.tasks_done;
      c[4].textContent = fmtRate(w.samples_per_second);
      c[5].textContent = w.threads || "all";
      c[6].textContent = w.render_version;
      c[7].textContent = w.failures;
      c[8].textContent = fmtAgo(w.last_seen_ms);
      return r.tr;
    });
    if (!workers.length) {
      const empty = list.loaded ? "No worker has registered." : list.empty("workers");
      body.replaceChildren(h("tr", {}, h("td", { colspan: 9, class: "muted" }, empty)));
    } else if (trs.length !== body.children.length || trs.some((tr, i) => body.children[i] !== tr)) {
      body.replaceChildren(...trs);
    }
  };
  const refresh = list.refresh;
  main.append(h("h1", {}, "Workers"),
    h("div", { class: "table-wrap" }, h("table", { id: "workers" },
      h("thead", {}, h("tr", {}, ["Name", "State", "Current task", "Tasks done", "Samples/s",
        "Threads", "Render version", "Failures", "Last seen"].map((c, i) =>
        h("th", { scope: "col", class: [5, 6].includes(i) ? "opt" : null }, c)))),
      body)));
  listeners.add((ev) => {
    if (ev.type === "resync" || ev.type.startsWith("worker_") || ev.type.startsWith("task_")) {
      refresh();
    }
  });
  refresh();
  setInterval(render, 5000);
}

// ---------------------------------------------------------------- start

// The job id of a page's path segment, or null where its percent-encoding is malformed.
function jobId(segment) {
  try {
    return decodeURIComponent(segment);
  } catch (_) {
    return null;
  }
}

function start() {
  const main = document.getElementById("main");
  main.replaceChildren();
  const path = location.pathname;
  const m = path.match(/^\/jobs\/([^/]+)$/);
  document.getElementById("nav-jobs").toggleAttribute("aria-current", path === "/" || !!m);
  document.getElementById("nav-workers").toggleAttribute("aria-current", path === "/workers");
  for (const id of ["nav-jobs", "nav-workers"]) {
    const el = document.getElementById(id);
    if (el.hasAttribute("aria-current")) el.setAttribute("aria-current", "page");
  }
  if (path === "/") jobsPage(main);
  else if (path === "/workers") workersPage(main);
  else if (m && jobId(m[1]) !== null) jobPage(main, jobId(m[1]));
  else main.append(h("h1", {}, "Not found"), h("p", {}, h("a", { href: "/" }, "All jobs")));
  if (document.visibilityState === "hidden") setLive(false, "paused while hidden");
  else connectEvents();
}

// A browser opens only six connections to one host, and each page's event stream holds one
// for as long as it is open: a page in a tab in the background, or left for another and
// kept (back-forward cache), closes its stream, and opens it again (it starts with a
// resync) when it is shown, so that any number of tabs leave room for the one in view.
function closeEvents() {
  if (stream) {
    stream.abort();
    stream = null;
  }
  setLive(false, "paused while hidden");
}
window.addEventListener("pagehide", closeEvents);
window.addEventListener("pageshow", (e) => {
  if (e.persisted && document.visibilityState === "visible" && !stream) connectEvents();
});
document.addEventListener("visibilitychange", () => {
  if (document.visibilityState === "hidden") closeEvents();
  else if (!stream) connectEvents();
});

start();
