//! The API's OpenAPI 3.1 document, served at `/api/openapi.json`. Kept beside the routes it
//! describes; a test checks that every route is in it.

use serde_json::{json, Value};

/// A route's entry: its summary, and its JSON body's schema for a POST.
fn op(summary: &str, body: Option<Value>) -> Value {
    let mut op = json!({
        "summary": summary,
        "security": [{ "token": [] }],
        "responses": {
            "200": { "description": "done; a change answers its state_id and the first frame that shows it" },
            "400": { "description": "a bad value, with the reason in error" },
            "401": { "description": "no or a wrong token; nothing changed" },
            "422": { "description": "refused by the wall, with the reason in error; nothing changed" },
            "503": { "description": "the wall is busy or over" }
        }
    });
    if let Some(schema) = body {
        op["requestBody"] = json!({
            "required": true,
            "content": { "application/json": { "schema": schema } }
        });
    }
    op
}

fn obj(properties: Value) -> Value {
    json!({ "type": "object", "additionalProperties": false, "properties": properties })
}

fn vec3() -> Value {
    json!({ "type": "array", "items": { "type": "number" }, "minItems": 3, "maxItems": 3 })
}

/// The whole document.
pub fn document() -> Value {
    let number = json!({ "type": "number" });
    let boolean = json!({ "type": "boolean" });
    let integer = json!({ "type": "integer" });
    json!({
        "openapi": "3.1.0",
        "info": {
            "title": "Tessera console API",
            "version": env!("CARGO_PKG_VERSION"),
            "description": "Steer and watch a running Tessera wall. Every change goes through the same checks and frame barrier as `tessera-master control`."
        },
        "components": { "securitySchemes": {
            "token": { "type": "http", "scheme": "bearer", "description": "the token tessera-master printed; the page's cookie works too" }
        }},
        "paths": {
            "/api/status": { "get": op("The wall's state, as an operator reads it", None) },
            "/api/figures": { "get": op("Live figures: fps, frame times, idle, per node", None) },
            "/api/events": { "get": op("Server-sent events: status, figures, picture", None) },
            "/api/wall.png": { "get": op("The whole wall, shrunk, bezels included", None) },
            "/api/heatmap.png": { "get": op("Which render node rendered each tile last, in the overlay's colours", None) },
            "/api/histogram": { "get": op("The volume's histogram: range and 256 counts", None) },
            "/api/openapi.json": { "get": op("This document", None) },
            "/api/input": { "post": op("Window input: Drag, Scroll or Key, as a window sends it", Some(json!({ "type": "object" }))) },
            "/api/camera": { "post": op("fit, home, orbit, or eye/target/up/fov", Some(obj(json!({
                "fit": boolean, "home": boolean, "orbit": boolean,
                "eye": vec3(), "target": vec3(), "up": vec3(), "fov": number
            })))) },
            "/api/quality": { "post": op("Shadows, AO rays, samples per pixel", Some(obj(json!({
                "shadows": boolean, "ao": integer, "spp": integer
            })))) },
            "/api/cuts": { "post": op("Cutting planes NX,NY,NZ,D (up to 4; none clears)", Some(obj(json!({
                "planes": { "type": "array", "items": { "type": "array", "items": number, "minItems": 4, "maxItems": 4 } }
            })))) },
            "/api/lights": { "post": op("The scene's lights, or these", Some(obj(json!({
                "scene": boolean, "lights": { "type": "array" }
            })))) },
            "/api/volume": { "post": op("Iso-values, step, time step, transfer function or preset", Some(obj(json!({
                "iso": { "type": "array", "items": number, "maxItems": 4 },
                "step": number, "time_step": integer,
                "transfer": { "type": "object" }, "preset": { "enum": ["ramp", "ct-bone", "ct-skin"] }
            })))) },
            "/api/playback": { "post": op("A time series: play, pause, speed, step", Some(obj(json!({
                "playing": boolean, "speed": number, "step": integer
            })))) },
            "/api/views": { "get": op("The saved views", None) },
            "/api/views/{name}": { "post": op("Save the camera as a view", None) },
            "/api/views/{name}/go": { "post": op("Go to a saved view", None) },
            "/api/overlay": { "post": op("The displays' overlay on or off", Some(obj(json!({ "on": boolean })))) },
            "/api/snapshot": { "post": op("Save the wall as the displays show it; answered with the files once written", Some(obj(json!({ "final": boolean })))) },
            "/api/probe": { "get": op("The volume under wall pixel x,y (query)", None) },
            "/api/record": { "post": op("Start or stop recording the session into a file of the --out folder", Some(obj(json!({
                "on": boolean, "path": { "type": "string" }
            })))) },
            "/api/replay": { "post": op("Replay a recorded session of the --out folder from the next frame on", Some(obj(json!({
                "path": { "type": "string" }
            })))) },
            "/api/particles": { "post": op("The colour map of particles' attributes", Some(obj(json!({
                "colormap": { "enum": ["viridis", "magma", "coolwarm", "greys"] }
            })))) }
        }
    })
}
