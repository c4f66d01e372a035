// The jobs page: the jobs and workers tables, live from /api/events, the job controls and
// the submit form.
"use strict";

(() => {
  const T = Tessera;
  const el = T.el;

  // ---- The jobs table ----

  /** Rows by job id, so that an update changes cells in place (a priority being typed
   *  keeps its focus and text). */
  const rows = new Map();

  function renderJobs(jobs) {
    const body = document.getElementById("jobs-body");
    const sorted = [...jobs].sort((a, b) => b.id - a.id);
    const seen = new Set();
    for (const job of sorted) {
      seen.add(job.id);
      let tr = rows.get(job.id);
      if (!tr) {
        tr = buildJobRow(job);
        rows.set(job.id, tr);
      }
      updateJobRow(tr, job);
    }
    for (const [id, tr] of rows) {
      if (!seen.has(id)) {
        tr.remove();
        rows.delete(id);
      }
    }
    // Keep the order (newest first) without rebuilding rows.
    const ordered = sorted.map((j) => rows.get(j.id));
    if (ordered.length === 0) {
      body.replaceChildren(
        el("tr", { class: "placeholder" }, el("td", { class: "empty", colspan: "13" }, "No jobs yet.")),
      );
    } else if (ordered.some((tr, i) => body.children[i] !== tr) || body.children.length !== ordered.length) {
      body.replaceChildren(...ordered);
    }
    document.getElementById("jobs-count").textContent = jobs.length ? `${jobs.length}` : "";
  }

  function buildJobRow(job) {
    const tr = el("tr", { dataset: { jobId: String(job.id) } });
    const cols = [
      ["id", "num mono"],
      ["scene", "scene"],
      ["owner", ""],
      ["state", ""],
      ["progress", ""],
      ["pass", "num"],
      ["rate", "num"],
      ["eta", "num"],
      ["priority", "num"],
      ["workers", "num"],
      ["size", "num mono"],
      ["actions", ""],
      ["image", ""],
    ];
    for (const [col, cls] of cols) tr.append(el("td", { class: cls, dataset: { col } }));
    const link = el("a", { href: `/jobs/${job.id}`, "aria-label": `Open job ${job.id}` }, String(job.id));
    cell(tr, "id").append(link);

    const controls = el("span", { class: "actions" });
    for (const [action, label, cls] of [
      ["pause", "Pause", ""],
      ["resume", "Resume", ""],
      ["cancel", "Cancel", "danger"],
    ]) {
      controls.append(
        el(
          "button",
          {
            type: "button",
            class: cls,
            dataset: { action },
            "aria-label": `${label} job ${job.id}`,
            onclick: (ev) => T.control(job.id, action, ev.currentTarget, refresh),
          },
          label,
        ),
      );
    }
    cell(tr, "actions").append(controls);

    const priority = el("input", {
      type: "number",
      step: "1",
      class: "priority",
      dataset: { action: "priority" },
      "aria-label": `Priority of job ${job.id}`,
    });
    priority.addEventListener("change", () => T.changePriority(job.id, priority, refresh));
    priority.addEventListener("keydown", (ev) => {
      if (ev.key === "Escape") {
        priority.value = priority.dataset.current;
        priority.blur();
      }
    });
    cell(tr, "priority").append(priority, el("span", { class: "priority-text" }));

    cell(tr, "image").append(
      el(
        "span",
        { class: "actions" },
        el(
          "a",
          {
            class: "button",
            href: `/api/jobs/${job.id}/image.png`,
            download: `job-${job.id}.png`,
            dataset: { action: "download-png" },
            "aria-label": `Download job ${job.id} as PNG`,
          },
          "PNG",
        ),
        el(
          "a",
          {
            class: "button",
            href: `/api/jobs/${job.id}/image.exr`,
            download: `job-${job.id}.exr`,
            dataset: { action: "download-exr" },
            "aria-label": `Download job ${job.id} as EXR`,
          },
          "EXR",
        ),
      ),
    );
    return tr;
  }

  function cell(tr, col) {
    return tr.querySelector(`td[data-col="${col}"]`);
  }

  function updateJobRow(tr, job) {
    tr.dataset.state = job.state;
    const scene = cell(tr, "scene");
    scene.replaceChildren(el("span", { title: job.scene }, job.scene));
    if (job.error) scene.append(el("span", { class: "err" }, job.error));
    cell(tr, "owner").textContent = job.owner || "—";
    cell(tr, "state").replaceChildren(T.stateBadge(job.state));
    cell(tr, "progress").replaceChildren(T.bar(job.progress, job.state));
    cell(tr, "pass").textContent = T.FINISHED.has(job.state) ? "—" : String(job.pass);
    cell(tr, "rate").textContent = job.state === "running" ? T.rate(job.samples_per_second) : "—";
    cell(tr, "eta").textContent = job.state === "running" ? T.duration(job.eta_seconds) : "—";
    cell(tr, "workers").textContent = String(job.workers);
    cell(tr, "size").textContent = `${job.width}×${job.height} · ${job.spp}`;
    cell(tr, "size").title = `${job.width}×${job.height} pixels, ${job.spp} samples per pixel`;

    const may = T.canControl(job);
    const allowed = T.actionsFor(job.state);
    for (const button of tr.querySelectorAll("button[data-action]")) {
      button.hidden = !may;
      if (!button.dataset.busy) button.disabled = !allowed[button.dataset.action];
    }
    const input = cell(tr, "priority").querySelector("input");
    const text = cell(tr, "priority").querySelector(".priority-text");
    input.dataset.current = String(job.priority);
    const editable = may && !T.FINISHED.has(job.state);
    input.hidden = !editable;
    text.hidden = editable;
    text.textContent = String(job.priority);
    if (document.activeElement !== input) input.value = String(job.priority);
  }

  // ---- The workers table ----

  function renderWorkers(workers) {
    const body = document.getElementById("workers-body");
    document.getElementById("workers-count").textContent = workers.length ? `${workers.length}` : "";
    if (workers.length === 0) {
      body.replaceChildren(
        el("tr", { class: "placeholder" }, el("td", { class: "empty", colspan: "9" }, "No workers connected.")),
      );
      return;
    }
    const sorted = [...workers].sort((a, b) => a.id - b.id);
    body.replaceChildren(
      ...sorted.map((w) =>
        el(
          "tr",
          { dataset: { workerId: String(w.id), quarantined: w.quarantined ? "true" : "false" } },
          el("td", { class: "num mono" }, String(w.id)),
          el("td", {}, w.name),
          el("td", { class: "num" }, String(w.threads)),
          el("td", { class: "num" }, String(w.batches_in_flight)),
          el("td", { class: "num" }, T.count(w.batches_done)),
          el("td", { class: "num" }, T.rate(w.samples_per_second)),
          el("td", { class: "num" }, T.ago(w.last_heard_seconds)),
          el("td", { class: w.strikes > 0 ? "num flag-bad" : "num" }, String(w.strikes)),
          el(
            "td",
            {},
            w.quarantined
              ? el("span", { class: "flag-bad" }, `quarantined${w.quarantine_reason ? `: ${w.quarantine_reason}` : ""}`)
              : el("span", { class: "muted" }, "no"),
          ),
        ),
      ),
    );
  }

  function renderSummary(jobs, workers) {
    const by = (s) => jobs.filter((j) => j.state === s).length;
    document.getElementById("sum-running").textContent = by("running");
    document.getElementById("sum-queued").textContent = by("queued");
    document.getElementById("sum-paused").textContent = by("paused");
    document.getElementById("sum-workers").textContent = workers.length;
    document.getElementById("sum-threads").textContent = workers.reduce((n, w) => n + w.threads, 0);
    document.getElementById("sum-rate").textContent = T.rate(
      workers.reduce((n, w) => n + (w.samples_per_second || 0), 0),
    );
  }

  function render(status) {
    const jobs = status.jobs || [];
    const workers = status.workers || [];
    renderJobs(jobs);
    renderWorkers(workers);
    renderSummary(jobs, workers);
  }

  async function refresh() {
    try {
      render(await T.api("GET", "/api/jobs"));
    } catch (e) {
      T.showError(e.message);
    }
  }

  // ---- The submit form ----

  /** The asset paths a scene refers to: every `file = "…"` outside comments (meshes and
   *  image textures), each once, in order. */
  function referencedFiles(text) {
    const found = [];
    const pattern = /(?:^|[\s{,])file\s*=\s*(?:"((?:[^"\\]|\\.)*)"|'([^']*)')/g;
    for (const line of text.split(/\r?\n/)) {
      const code = stripComment(line);
      for (const m of code.matchAll(pattern)) {
        const raw = m[1] !== undefined ? m[1].replace(/\\(.)/g, "$1") : m[2];
        const path = raw.replace(/^\.\//, "");
        if (path && !found.includes(path)) found.push(path);
      }
    }
    return found;
  }

  /** The line without a `#` comment (a `#` inside a string stays). */
  function stripComment(line) {
    let quote = null;
    for (let i = 0; i < line.length; i++) {
      const c = line[i];
      if (quote) {
        if (c === "\\" && quote === '"') i++;
        else if (c === quote) quote = null;
      } else if (c === '"' || c === "'") {
        quote = c;
      } else if (c === "#") {
        return line.slice(0, i);
      }
    }
    return line;
  }

  /** The picked file for `ref`: the one at that path under the picked folder, else one
   *  whose path ends with it, else one with its file name. */
  function pick(ref, files) {
    const under = (f) => (f.webkitRelativePath || "").split("/").slice(1).join("/");
    const base = ref.split("/").pop();
    return (
      files.find((f) => under(f) === ref) ||
      files.find((f) => (f.webkitRelativePath || "").endsWith(`/${ref}`)) ||
      files.find((f) => f.name === base) ||
      null
    );
  }

  function setupSubmit() {
    const form = document.getElementById("submit-form");
    const sceneInput = document.getElementById("submit-scene");
    const folderInput = document.getElementById("submit-folder");
    const assetsInput = document.getElementById("submit-assets");
    const map = document.getElementById("submit-map");
    const error = document.getElementById("submit-error");
    const result = document.getElementById("submit-result");
    const button = document.getElementById("submit-button");
    let refs = [];

    function pickedFiles() {
      return [...folderInput.files, ...assetsInput.files];
    }

    function showMap() {
      const files = pickedFiles();
      if (!sceneInput.files.length) {
        map.replaceChildren(el("li", { class: "muted" }, "Pick a scene file."));
        return;
      }
      if (refs.length === 0) {
        map.replaceChildren(el("li", { class: "muted" }, "The scene refers to no files."));
        return;
      }
      map.replaceChildren(
        ...refs.map((ref) => {
          const f = pick(ref, files);
          return f
            ? el(
                "li",
                { class: "found", dataset: { asset: ref } },
                `${ref} ← ${f.webkitRelativePath || f.name} (${T.count(f.size)} bytes)`,
              )
            : el("li", { class: "missing", dataset: { asset: ref } }, `${ref}: not among the picked files`);
        }),
      );
    }

    sceneInput.addEventListener("change", async () => {
      refs = [];
      error.textContent = "";
      const file = sceneInput.files[0];
      if (file) {
        try {
          refs = referencedFiles(await file.text());
        } catch (e) {
          error.textContent = `${file.name}: cannot be read (${e.message})`;
        }
      }
      showMap();
    });
    folderInput.addEventListener("change", showMap);
    assetsInput.addEventListener("change", showMap);

    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      error.textContent = "";
      result.replaceChildren();
      const scene = sceneInput.files[0];
      if (!scene) {
        error.textContent = "Pick a scene file (.toml).";
        return;
      }
      // The scene may have been picked before a change to it on disk: read it again.
      try {
        refs = referencedFiles(await scene.text());
      } catch (e) {
        error.textContent = `${scene.name}: cannot be read (${e.message})`;
        return;
      }
      showMap();
      const data = new FormData();
      data.append("scene", scene, scene.name);
      const files = pickedFiles();
      const missing = [];
      for (const ref of refs) {
        const f = pick(ref, files);
        if (f) data.append("asset", f, ref);
        else missing.push(ref);
      }
      if (missing.length) {
        error.textContent = `${scene.name} refers to ${missing.join(", ")}: pick its folder or the file${missing.length > 1 ? "s" : ""}`;
        return;
      }
      for (const name of ["width", "height", "spp", "priority", "time", "noise", "noise_absolute", "noise_min"]) {
        const input = document.getElementById(`submit-${name}`);
        if (input.validity && input.validity.badInput) {
          error.textContent = `${input.labels[0].textContent}: not a number`;
          return;
        }
        const value = input.value.trim();
        if (value !== "") data.append(name, value);
      }
      button.disabled = true;
      try {
        const job = await T.api("POST", "/api/jobs", data);
        result.replaceChildren(
          "Submitted ",
          el("a", { href: `/jobs/${job.id}`, dataset: { submitted: String(job.id) } }, `job ${job.id}`),
          ` (${job.width}×${job.height}, ${job.spp} spp)`,
        );
        refresh();
      } catch (e) {
        error.textContent = e.message;
      } finally {
        button.disabled = false;
      }
    });
  }

  // ---- Start ----

  function setConn(state) {
    const conn = document.getElementById("conn");
    conn.dataset.conn = state;
    conn.textContent = state === "live" ? "live" : state === "reconnecting" ? "reconnecting…" : "offline";
  }

  document.addEventListener("DOMContentLoaded", async () => {
    const session = await T.session(() => {
      document.getElementById("submit-panel").hidden = !T.canSubmit();
      setupSubmit();
      refresh();
      T.events(render, setConn, () => session.recheck());
    });
  });
})();
