// The server's JSON API as the page calls it (the routes are listed in t2m/serve/server.py):
// every failure becomes an Error whose message is a sentence for the page to show.

export async function callApi(url, options) {
  let response;
  try {
    response = await fetch(url, options);
  } catch (error) {
    throw new Error("the server cannot be reached (is python -m t2m.serve still running?)");
  }
  let data = null;
  try { data = await response.json(); } catch (error) { data = null; }
  if (!response.ok) {
    throw new Error((data && data.error) || `the server answered ${response.status}`);
  }
  return data;
}

// POST a JSON body (generate, edit); the answer's JSON.
export function postJson(url, body) {
  return callApi(url, {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body),
  });
}
