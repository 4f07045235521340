// The service's REST API as the pages (the viewer, the review page) call it: the API key a page is given or this
// browser remembers, sent as a bearer token, and an error answer turned into an Error that says what the service said.

const KEY_ITEM = "sweepcast-key";

/** The API key a page starts with: ``?key=`` in its address, else the last one entered in this browser ("": none). */
export function startingKey() {
  return new URLSearchParams(location.search).get("key") || localStorage.getItem(KEY_ITEM) || "";
}

/** Remember ``key`` for this browser's next pages. */
export function rememberKey(key) {
  localStorage.setItem(KEY_ITEM, key);
}

/** ``extra`` headers with the Authorization of ``key`` (none for ""). */
export function authHeaders(key, extra = {}) {
  return key ? { ...extra, Authorization: `Bearer ${key}` } : extra;
}

/** ``fetch(path, init)`` with ``key``: the Response when it is ok, else an Error whose message is the service's
 * ``detail`` (its status text where the body is not JSON) and whose ``status`` is the HTTP status. */
export async function api(path, key, init = {}) {
  const response = await fetch(path, { ...init, headers: authHeaders(key, init.headers) });
  if (response.ok) return response;
  let detail = response.statusText;
  try {
    const body = await response.json();
    detail = typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail);
  } catch (_) { /* not JSON */ }
  const error = new Error(detail);
  error.status = response.status;
  throw error;
}
