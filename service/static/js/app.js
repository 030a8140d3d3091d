// The dashboard's entry: a hash router (#/, #/new, #/jobs/{id}) and the API key prompt.

import { setApiKey, setUnauthorizedHandler } from "./api.js";
import { jobView } from "./job.js";
import { jobsCard } from "./jobs.js";
import { newJobCard } from "./newjob.js";
import { h, toast } from "./util.js";

const main = document.getElementById("main");
let teardown = () => {};

function home(focusNew) {
  const jobs = jobsCard();
  main.replaceChildren(h("div.home", newJobCard({ focus: focusNew }), jobs));
  document.title = "cloud2cnc";
  return () => jobs.destroy();
}

function route() {
  teardown();
  teardown = () => {};
  const hash = location.hash.replace(/^#/, "") || "/";
  const m = /^\/jobs\/([^/?#]+)\/?$/.exec(hash);
  for (const a of document.querySelectorAll("header nav a")) {
    const target = a.getAttribute("href");
    a.toggleAttribute("aria-current", target === `#${hash}` || (target === "#/" && Boolean(m)));
  }
  if (m) {
    teardown = jobView(decodeURIComponent(m[1]), main);
  } else if (hash === "/" || hash === "/new") {
    teardown = home(hash === "/new");
  } else {
    main.replaceChildren(h("section.card", h("h1", "Not found"), h("p", `Nothing at #${hash}. `, h("a", { href: "#/" }, "Go to the jobs"))));
  }
  if (document.activeElement && document.activeElement !== document.body && !main.contains(document.activeElement)
      && !document.querySelector("header")?.contains(document.activeElement)) {
    main.focus({ preventScroll: true });
  }
}

// API key: asked for only when the server answers 401 (CLOUD2CNC_API_KEY is set); kept for this tab.
const keyForm = document.getElementById("apikey-form");
setUnauthorizedHandler(() => {
  if (!keyForm.hidden) return;
  keyForm.hidden = false;
  toast("This server needs an API key: enter it at the top right.", "error");
  document.getElementById("apikey").focus();
});
keyForm.addEventListener("submit", (e) => {
  e.preventDefault();
  setApiKey(document.getElementById("apikey").value.trim());
  keyForm.hidden = true;
  route();
});

window.addEventListener("hashchange", route);
route();
