// Shared by the jobs page and a job's page: the API client, the session (login, logout,
// who is signed in and what their role may do), the status event stream, formatting.
// Plain browser JavaScript, no framework and no build step: the coordinator embeds this
// folder as it is.
"use strict";

const Tessera = (() => {
  /** An API call that failed, with the server's one-line message. */
  class ApiError extends Error {
    constructor(status, message) {
      super(message);
      this.status = status;
    }
  }

  /** Calls the API; resolves to the parsed JSON body (null for 204), rejects with ApiError. */
  async function api(method, path, body) {
    const init = { method, credentials: "same-origin", headers: {} };
    if (body instanceof FormData) {
      init.body = body;
    } else if (body !== undefined) {
      init.headers["Content-Type"] = "application/json";
      init.body = JSON.stringify(body);
    }
    let response;
    try {
      response = await fetch(path, init);
    } catch (e) {
      throw new ApiError(0, `${method} ${path}: the coordinator does not answer (${e.message})`);
    }
    const text = await response.text();
    let json = null;
    if (text) {
      try {
        json = JSON.parse(text);
      } catch (_) {
        json = null;
      }
    }
    if (!response.ok) {
      const said = json && typeof json.error === "string" ? json.error : text.trim().split("\n")[0];
      throw new ApiError(response.status, said || `${method} ${path}: HTTP ${response.status}`);
    }
    return json;
  }

  // ---- The session ----

  /** The signed-in principal {name, role}, or null before login. */
  let me = null;

  /** Whether the signed-in role may submit, pause, resume, cancel and change priorities
   *  (the server checks again; this only decides what is shown). */
  function canControl(job) {
    if (!me) return false;
    if (me.role === "admin") return true;
    const submitter = me.role === "submitter" || me.role === "submit";
    return submitter && (job === undefined || job.owner === me.name);
  }
  function canSubmit() {
    return !!me && (me.role === "admin" || me.role === "submitter" || me.role === "submit");
  }

  /** Asks who is signed in; shows the login form on 401. Calls `start` once signed in. */
  async function session(start) {
    const loginView = document.getElementById("login");
    const appView = document.getElementById("app");
    const form = document.getElementById("login-form");
    const tokenInput = document.getElementById("login-token");
    const loginError = document.getElementById("login-error");
    let started = false;

    async function check() {
      try {
        me = await api("GET", "/api/whoami");
      } catch (e) {
        if (e.status === 401) {
          me = null;
        } else {
          showError(e.message);
          me = null;
          loginError.textContent = e.message;
        }
      }
      renderWho();
      loginView.hidden = !!me;
      appView.hidden = !me;
      document.body.dataset.session = me ? "in" : "out";
      if (me) {
        if (!started) {
          started = true;
          start(me);
        }
      } else {
        tokenInput.focus();
      }
    }

    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      loginError.textContent = "";
      const token = tokenInput.value.trim();
      if (!token) {
        loginError.textContent = "Enter a token.";
        return;
      }
      const button = form.querySelector("button[type=submit]");
      button.disabled = true;
      try {
        await api("POST", "/api/login", { token });
        tokenInput.value = "";
        // A session that expired while the page was open: its streams stopped, so start
        // the page again rather than patch each of them.
        if (started) location.reload();
        else await check();
      } catch (e) {
        loginError.textContent = e.message;
      } finally {
        button.disabled = false;
      }
    });

    document.getElementById("logout").addEventListener("click", async () => {
      try {
        await api("POST", "/api/logout");
      } catch (e) {
        showError(e.message);
      }
      // Everything shown belonged to the session: start again from a clean page.
      location.reload();
    });

    await check();
    return { recheck: check };
  }

  function renderWho() {
    const who = document.getElementById("who");
    const logout = document.getElementById("logout");
    if (!who) return;
    if (me) {
      who.replaceChildren(el("b", {}, me.name), ` · ${me.role}`);
      who.dataset.role = me.role;
      // An open coordinator lets everyone in as the admin "anonymous": nothing to log out of.
      logout.hidden = me.name === "anonymous";
    } else {
      who.replaceChildren();
      logout.hidden = true;
    }
  }

  // ---- The one-line error banner ----

  function showError(message) {
    const line = document.getElementById("error");
    if (!line) return;
    line.querySelector("span").textContent = message.split("\n")[0];
    line.hidden = false;
  }
  function clearError() {
    const line = document.getElementById("error");
    if (line) line.hidden = true;
  }
  document.addEventListener("DOMContentLoaded", () => {
    const line = document.getElementById("error");
    if (line) line.querySelector("button").addEventListener("click", clearError);
  });

  // ---- Server-sent status events, reconnecting ----

  /** Follows `/api/events`; calls `onStatus({jobs, workers})` with each event, and
   *  `onConn("live"|"reconnecting")`. EventSource retries by itself after a dropped
   *  connection, but gives up for good on an HTTP error (an expired session, a restart
   *  that answered 503); then this opens a new one with a growing delay, after checking
   *  the session. */
  function events(onStatus, onConn, recheck) {
    let delay = 500;
    let source = null;
    function open() {
      source = new EventSource("/api/events", { withCredentials: true });
      source.addEventListener("open", () => {
        delay = 500;
        onConn("live");
      });
      source.addEventListener("status", (ev) => {
        try {
          onStatus(JSON.parse(ev.data));
        } catch (e) {
          showError(`a status event could not be read: ${e.message}`);
        }
      });
      source.addEventListener("error", () => {
        onConn("reconnecting");
        if (source.readyState === EventSource.CLOSED) {
          setTimeout(async () => {
            if (recheck) await recheck();
            if (me) open();
          }, delay);
          delay = Math.min(delay * 2, 8000);
        }
      });
    }
    open();
    return () => source && source.close();
  }

  // ---- Job controls, shared by both pages ----

  /** Pauses, resumes or cancels job `id`; resolves once the server answered. */
  function act(id, action) {
    return api("POST", `/api/jobs/${id}/${action}`);
  }
  function setPriority(id, priority) {
    return api("POST", `/api/jobs/${id}/priority`, { priority });
  }
  /** A control button pressed: acts, shows the answer's error if any, then `after()`. */
  async function control(id, action, button, after) {
    button.dataset.busy = "1";
    button.disabled = true;
    try {
      await act(id, action);
      clearError();
    } catch (e) {
      showError(e.message);
    } finally {
      delete button.dataset.busy;
      after();
    }
  }
  /** A priority input changed: sets it (a whole number), or puts the old value back. */
  async function changePriority(id, input, after) {
    const value = Number(input.value);
    if (input.value === "" || !Number.isInteger(value)) {
      showError(`job ${id}: the priority must be a whole number`);
      input.value = input.dataset.current;
      return;
    }
    try {
      await setPriority(id, value);
      clearError();
    } catch (e) {
      showError(e.message);
      input.value = input.dataset.current;
    }
    after();
  }
  /** Which of pause/resume/cancel make sense in `state`. */
  function actionsFor(state) {
    return {
      pause: state === "queued" || state === "running",
      resume: state === "paused",
      cancel: state === "queued" || state === "running" || state === "paused",
    };
  }
  const FINISHED = new Set(["done", "cancelled", "failed"]);

  // ---- Formatting ----

  function duration(seconds) {
    if (seconds === null || seconds === undefined || !isFinite(seconds)) return "—";
    let s = Math.max(0, Math.round(seconds));
    if (s < 60) return `${s}s`;
    const h = Math.floor(s / 3600);
    const m = Math.floor((s % 3600) / 60);
    s %= 60;
    if (h > 0) return `${h}h ${String(m).padStart(2, "0")}m`;
    return `${m}m ${String(s).padStart(2, "0")}s`;
  }
  function rate(perSecond) {
    if (!perSecond) return "—";
    const units = [[1e9, "G"], [1e6, "M"], [1e3, "k"]];
    for (const [scale, unit] of units) {
      if (perSecond >= scale) return `${(perSecond / scale).toFixed(perSecond >= scale * 100 ? 0 : 2)} ${unit}/s`;
    }
    return `${perSecond.toFixed(0)} /s`;
  }
  function count(n) {
    return Number(n).toLocaleString("en-US");
  }
  function percent(fraction) {
    return `${(Math.min(1, Math.max(0, fraction || 0)) * 100).toFixed(1)}%`;
  }
  function ago(seconds) {
    if (seconds === null || seconds === undefined) return "—";
    if (seconds < 1) return "now";
    return `${duration(seconds)} ago`;
  }

  /** Creates an element: el("td", {class: "num", dataset: {x: 1}}, child, "text", ...). */
  function el(tag, attrs, ...children) {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === undefined || v === null || v === false) continue;
      if (k === "dataset") Object.assign(node.dataset, v);
      else if (k === "class") node.className = v;
      else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
      else if (k === "text") node.textContent = v;
      else node.setAttribute(k, v === true ? "" : v);
    }
    for (const c of children) {
      if (c !== null && c !== undefined) node.append(c);
    }
    return node;
  }

  /** A progress bar element showing `fraction`, coloured by `state`. */
  function bar(fraction, state, wide) {
    const fill = el("i");
    fill.style.width = percent(fraction);
    return el(
      "div",
      {
        class: wide ? "bar wide" : "bar",
        role: "progressbar",
        "aria-valuemin": "0",
        "aria-valuemax": "100",
        "aria-valuenow": (Math.min(1, fraction || 0) * 100).toFixed(1),
        dataset: { state },
      },
      fill,
      el("b", {}, percent(fraction)),
    );
  }

  function stateBadge(state) {
    return el("span", { class: `state state-${state}`, dataset: { state } }, state);
  }

  return {
    ApiError,
    api,
    session,
    me: () => me,
    canControl,
    canSubmit,
    showError,
    clearError,
    events,
    act,
    setPriority,
    control,
    changePriority,
    actionsFor,
    FINISHED,
    duration,
    rate,
    count,
    percent,
    ago,
    el,
    bar,
    stateBadge,
  };
})();
