// Starts Swagger UI on /docs. A file of its own, not an inline script, so the page keeps
// the same Content-Security-Policy as the map (scripts from this origin only).
window.addEventListener("DOMContentLoaded", () => {
  window.ui = SwaggerUIBundle({
    url: "/openapi.json",
    dom_id: "#swagger-ui",
    deepLinking: true,
    // The "Authorize" button keeps the token for the session only.
    persistAuthorization: false,
    presets: [SwaggerUIBundle.presets.apis, SwaggerUIBundle.SwaggerUIStandalonePreset],
    layout: "BaseLayout",
  });
});
