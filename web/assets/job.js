// A job's page: its live image on a canvas, fed by the WebSocket /api/jobs/{id}/live, its
// status line and its controls.
"use strict";

(() => {
  const T = Tessera;

  /** "TSR1", the first four bytes of every binary update (little-endian u32). */
  const MAGIC = 0x54535231;
  const FLAG_RESET = 1;
  const FLAG_FINAL = 2;
  const HEADER_BYTES = 20;

  const match = location.pathname.match(/^\/jobs\/(\d+)\/?$/);
  const jobId = match ? Number(match[1]) : null;

  let job = null;
  /** The frame of a sequence shown (`null`: a still, or before the first status). */
  let frame = null;
  /** Opens the live socket on the frame shown; set by `live`. */
  let reopen = null;
  /** The socket open now, and a count of sockets opened: a socket's close handler that is
   *  not the newest's (the frame changed) does nothing. */
  let socketNow = null;
  let sockets = 0;

  // ---- The live image ----

  /** The image as received: the canvas is only ever drawn from it, so that a reset or a
   *  delta touches the pixels it names and no others. */
  let image = null;
  let width = 0;
  let height = 0;
  let final = false;
  /** Arrival times (ms) of the binary updates of the last second, for the readout. */
  const arrivals = [];
  let updates = 0;

  function setSize(w, h) {
    const canvas = document.getElementById("live");
    if (w === width && h === height && image) return;
    width = w;
    height = h;
    canvas.width = w;
    canvas.height = h;
    image = new ImageData(w, h);
    document.getElementById("image-size").textContent = `${w}×${h}`;
    fit();
  }

  /** Scales the canvas to fit the stage: whole multiples when it is smaller (sharp
   *  pixels), a fraction when larger; never stretched out of shape. */
  function fit() {
    const canvas = document.getElementById("live");
    const stage = document.getElementById("stage");
    if (!width || !height) return;
    const room = { w: stage.clientWidth - 16, h: stage.clientHeight - 16 };
    let scale = Math.min(room.w / width, room.h / height);
    if (scale >= 1) scale = Math.floor(scale);
    scale = Math.max(scale, 0.05);
    canvas.style.width = `${Math.round(width * scale)}px`;
    canvas.style.height = `${Math.round(height * scale)}px`;
    document.getElementById("zoom").textContent = `${Math.round(scale * 100)}%`;
  }

  /** Applies one binary update; throws with a one-line reason when it is malformed. */
  function apply(buffer) {
    if (!image) throw new Error("an image update came before the hello message");
    if (buffer.byteLength < HEADER_BYTES) throw new Error(`an update of ${buffer.byteLength} bytes is too short`);
    const view = new DataView(buffer);
    if (view.getUint32(0, true) !== MAGIC) throw new Error("an update does not start with TSR1");
    const version = view.getBigUint64(4, true);
    const flags = view.getUint32(12, true);
    const runs = view.getUint32(16, true);
    const pixels = width * height;
    const data = image.data;
    if (flags & FLAG_RESET) data.fill(0);
    let offset = HEADER_BYTES;
    let top = flags & FLAG_RESET ? 0 : height;
    let bottom = flags & FLAG_RESET ? height - 1 : -1;
    for (let r = 0; r < runs; r++) {
      if (offset + 8 > buffer.byteLength) throw new Error(`run ${r} of ${runs} is cut off`);
      const start = view.getUint32(offset, true);
      const len = view.getUint32(offset + 4, true);
      offset += 8;
      if (start + len > pixels) throw new Error(`run ${r} (${start}+${len}) is outside the ${width}×${height} image`);
      if (offset + len * 4 > buffer.byteLength) throw new Error(`run ${r} of ${runs} is cut off`);
      data.set(new Uint8ClampedArray(buffer, offset, len * 4), start * 4);
      offset += len * 4;
      if (len > 0) {
        top = Math.min(top, Math.floor(start / width));
        bottom = Math.max(bottom, Math.floor((start + len - 1) / width));
      }
    }
    // Only the rows the update touched are copied to the canvas.
    if (bottom >= top) {
      const ctx = document.getElementById("live").getContext("2d", { willReadFrequently: true });
      ctx.putImageData(image, 0, 0, 0, top, width, bottom - top + 1);
    }
    const canvas = document.getElementById("live");
    updates++;
    canvas.dataset.version = version.toString();
    canvas.dataset.updates = String(updates);
    document.getElementById("image-version").textContent = version.toString();
    const now = performance.now();
    arrivals.push(now);
    if (flags & FLAG_FINAL) {
      final = true;
      canvas.dataset.final = "true";
    }
  }

  function showRate() {
    const now = performance.now();
    while (arrivals.length && now - arrivals[0] > 1000) arrivals.shift();
    document.getElementById("fps").textContent = String(arrivals.length);
  }

  // ---- The WebSocket, reconnecting ----

  function live(recheck) {
    let delay = 500;
    const note = document.getElementById("live-note");
    function open() {
      const scheme = location.protocol === "https:" ? "wss:" : "ws:";
      const query = frame === null ? "" : `?frame=${frame}`;
      const socket = new WebSocket(`${scheme}//${location.host}/api/jobs/${jobId}/live${query}`);
      const mine = ++sockets;
      socketNow = socket;
      socket.binaryType = "arraybuffer";
      let heard = false;
      socket.addEventListener("open", () => setConn("live"));
      socket.addEventListener("message", (ev) => {
        heard = true;
        delay = 500;
        try {
          if (typeof ev.data === "string") {
            const msg = JSON.parse(ev.data);
            if (msg.type === "hello") setSize(msg.width, msg.height);
            else if (msg.type === "status") renderStatus(msg.job);
          } else {
            apply(ev.data);
          }
        } catch (e) {
          T.showError(`live image: ${e.message}`);
        }
      });
      socket.addEventListener("close", async (ev) => {
        if (mine !== sockets) return;
        if (final) {
          setConn("closed");
          note.textContent = "final image";
          return;
        }
        setConn("reconnecting");
        note.textContent = ev.reason ? `disconnected: ${ev.reason}` : "disconnected";
        // A socket refused before its first message may be an expired session.
        if (!heard && recheck) await recheck();
        if (!T.me()) return;
        setTimeout(() => {
          if (mine === sockets) open();
        }, delay);
        delay = Math.min(delay * 2, 8000);
      });
    }
    reopen = open;
    open();
  }

  /** Shows frame `f` of the sequence: a socket of its own, the downloads of that frame. */
  function showFrame(f) {
    frame = f;
    final = false;
    document.getElementById("live").dataset.final = "false";
    document.getElementById("live").dataset.frame = String(f);
    setDownloads();
    if (socketNow) socketNow.close();
    if (reopen) reopen();
  }

  // How the job may end before its spp: its noise target (pixels stop as they reach it,
  // so the samples left are a bound and there is no ETA) and its time budget; once done,
  // which of them ended it.
  function renderEnds(j) {
    const parts = [];
    if (j.ended_by) {
      parts.push(`ended by its ${j.ended_by}`);
    } else if (!T.FINISHED.has(j.state)) {
      if (j.noise) {
        parts.push(`at ${j.noise.kind} noise ${j.noise.target}, each pixel ≥ ${j.noise.min_samples} spp first`);
      }
      if (j.time_limit_seconds != null) parts.push(`at a ${j.time_limit_seconds} s budget`);
    }
    document.getElementById("job-ends-wrap").hidden = parts.length === 0;
    document.getElementById("job-ends").textContent = parts.join(" or ");
  }

  /** A sequence's frame selector and figures, from its status. */
  function renderFrames(j) {
    const select = document.getElementById("job-frame");
    const wrap = document.getElementById("job-frames-wrap");
    const sequence = Array.isArray(j.frames);
    select.hidden = !sequence;
    document.getElementById("job-frame-label").hidden = !sequence;
    wrap.hidden = !sequence;
    if (!sequence) return;
    const frames = j.frame_progress || [];
    if (select.options.length !== frames.length) {
      select.replaceChildren(...frames.map((f) => new Option(String(f.frame), String(f.frame))));
      if (frame === null) {
        frame = j.frames[0];
        setDownloads();
      }
      select.value = String(frame);
    }
    frames.forEach((f, k) => {
      const text = `${f.frame} · ${Math.floor(f.progress * 100)}%${f.previewed ? "" : " · no preview yet"}`;
      if (select.options[k] && select.options[k].text !== text) select.options[k].text = text;
    });
    const done = frames.filter((f) => f.progress >= 1).length;
    const previewed = frames.filter((f) => f.previewed).length;
    document.getElementById("job-frames").textContent =
      `${j.frames[0]}–${j.frames[1]}: ${done} of ${frames.length} done, ${previewed} previewed`;
    Object.assign(wrap.dataset, { done: String(done), previewed: String(previewed), count: String(frames.length) });
  }

  function setConn(state) {
    const conn = document.getElementById("conn");
    conn.dataset.conn = state;
    conn.textContent = state === "live" ? "live" : state === "reconnecting" ? "reconnecting…" : "closed";
  }

  // ---- Status and controls ----

  function renderStatus(j) {
    if (!j || j.id !== jobId) return;
    job = j;
    document.title = `Tessera · job ${j.id} · ${j.state}`;
    document.getElementById("job-title").textContent = `Job ${j.id}`;
    document.getElementById("job-scene").textContent = j.scene;
    document.getElementById("job-badge").replaceChildren(T.stateBadge(j.state));
    const state = document.getElementById("job-state");
    state.textContent = j.error ? `${j.state}: ${j.error}` : j.state;
    state.dataset.state = j.state;
    // The figures as numbers too, for scripts and tests that read the page.
    Object.assign(document.getElementById("status-line").dataset, {
      state: j.state,
      pass: String(j.pass),
      samplesDone: String(j.samples_done),
      samplesTotal: String(j.samples_total),
      progress: String(j.progress),
    });
    document.getElementById("job-pass").textContent = T.FINISHED.has(j.state) ? "—" : `${j.pass} of 2`;
    document.getElementById("job-progress-wrap").replaceChildren(T.bar(j.progress, j.state, true));
    document.getElementById("job-samples").textContent = `${T.count(j.samples_done)} / ${T.count(j.samples_total)}`;
    document.getElementById("job-rate").textContent = j.state === "running" ? T.rate(j.samples_per_second) : "—";
    document.getElementById("job-elapsed").textContent = T.duration(j.elapsed_seconds);
    document.getElementById("job-eta").textContent = j.state === "running" ? T.duration(j.eta_seconds) : "—";
    document.getElementById("job-workers").textContent = String(j.workers);
    document.getElementById("job-priority-text").textContent = String(j.priority);
    document.getElementById("job-owner").textContent = j.owner || "—";
    renderEnds(j);
    renderFrames(j);

    const may = T.canControl(j);
    const allowed = T.actionsFor(j.state);
    for (const action of ["pause", "resume", "cancel"]) {
      const button = document.getElementById(`job-${action}`);
      button.hidden = !may;
      if (!button.dataset.busy) button.disabled = !allowed[action];
    }
    const input = document.getElementById("job-priority");
    const editable = may && !T.FINISHED.has(j.state);
    input.hidden = !editable;
    document.getElementById("job-priority-label").hidden = !editable;
    input.dataset.current = String(j.priority);
    if (document.activeElement !== input) input.value = String(j.priority);
    if (!width && j.width) setSize(j.width, j.height);
  }

  async function refresh() {
    try {
      renderStatus(await T.api("GET", `/api/jobs/${jobId}`));
    } catch (e) {
      T.showError(e.message);
    }
  }

  function setupControls() {
    for (const action of ["pause", "resume", "cancel"]) {
      const button = document.getElementById(`job-${action}`);
      button.setAttribute("aria-label", `${button.textContent} job ${jobId}`);
      button.addEventListener("click", () => T.control(jobId, action, button, refresh));
    }
    const input = document.getElementById("job-priority");
    input.addEventListener("change", () => T.changePriority(jobId, input, refresh));
    setDownloads();
    const select = document.getElementById("job-frame");
    select.addEventListener("change", () => showFrame(Number(select.value)));
  }

  /** The download links, of the frame shown for a sequence. */
  function setDownloads() {
    const query = frame === null ? "" : `?frame=${frame}`;
    const name = frame === null ? `job-${jobId}` : `job-${jobId}-frame-${frame}`;
    for (const ext of ["png", "exr"]) {
      const a = document.getElementById(`download-${ext}`);
      a.href = `/api/jobs/${jobId}/image.${ext}${query}`;
      a.download = `${name}.${ext}`;
    }
  }

  document.addEventListener("DOMContentLoaded", async () => {
    window.addEventListener("resize", fit);
    setInterval(showRate, 250);
    const session = await T.session(async () => {
      if (jobId === null) {
        T.showError(`${location.pathname}: not a job's page (expected /jobs/ID)`);
        return;
      }
      setupControls();
      try {
        renderStatus(await T.api("GET", `/api/jobs/${jobId}`));
      } catch (e) {
        T.showError(e.message);
        if (e.status === 404) return;
      }
      live(() => session.recheck());
      // The socket carries the status while the image changes; the events carry it when
      // only the state does (a pause, a queued job).
      T.events(
        (status) => renderStatus((status.jobs || []).find((j) => j.id === jobId)),
        () => {},
        () => session.recheck(),
      );
    });
  });
})();
