//! The page and three.js, compiled into the binary: the viewer works on a console with no network, and no
//! request leaves the machine.

/// (URL path, content type, bytes).
pub(crate) const ASSETS: &[(&str, &str, &[u8])] = &[
    ("/", "text/html; charset=utf-8", include_bytes!("../web/index.html")),
    ("/viewer.js", "text/javascript; charset=utf-8", include_bytes!("../web/viewer.js")),
    ("/viewer.css", "text/css; charset=utf-8", include_bytes!("../web/viewer.css")),
    (
        "/vendor/three/three.module.js",
        "text/javascript; charset=utf-8",
        include_bytes!("../web/vendor/three/three.module.js"),
    ),
    (
        "/vendor/three/three.core.js",
        "text/javascript; charset=utf-8",
        include_bytes!("../web/vendor/three/three.core.js"),
    ),
    ("/vendor/three/LICENSE", "text/plain; charset=utf-8", include_bytes!("../web/vendor/three/LICENSE")),
];

/// three.js's orbit controls import the bare name `three`, which a browser resolves only through an import map —
/// an inline script the content security policy forbids. So the one import line is pointed at the served file
/// (the rest of the file is served as vendored).
pub(crate) fn orbit_controls() -> Vec<u8> {
    const VENDORED: &str = include_str!("../web/vendor/three/OrbitControls.js");
    VENDORED.replacen("from 'three';", "from '/vendor/three/three.module.js';", 1).into_bytes()
}
