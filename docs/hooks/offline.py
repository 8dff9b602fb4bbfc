"""mkdocs hook: the site's search works from disk (``file://``) with nothing loaded from elsewhere.

Material's ``offline`` plugin (in mkdocs.yml) makes a site that opens from disk: it turns
``use_directory_urls`` off (every link names an ``.html`` file, never a folder), writes the search index
into a script as well (``search/search_index.js``: a page opened from disk may not fetch a file, but may
load a script), and adds the ``iframe-worker`` shim to the page's scripts, because a page opened from
disk may not start a web worker either and the search runs in one: under ``file://`` the shim runs the
worker in a hidden iframe instead. The plugin loads that shim from a CDN; this hook puts a copy of it,
kept in ``docs/hooks/vendor/`` (MIT licence beside it), into the site as
``assets/javascripts/iframe-worker-shim.js`` and points the pages at it, so search works offline too.
Over HTTP the shim does nothing and the search runs in a real worker.
"""
from __future__ import annotations

from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

SHIM = Path(__file__).resolve().parent / "vendor" / "iframe-worker-shim.js"
DEST = "assets/javascripts/iframe-worker-shim.js"


@event_priority(-100)  # after the offline plugin has added the shim's CDN address
def on_config(config):
    polyfills = config.extra.get("polyfills", [])
    config.extra["polyfills"] = [DEST if "iframe-worker" in str(p) and "://" in str(p) else p for p in polyfills]
    return config


def on_files(files, config):
    if DEST in (str(p) for p in config.extra.get("polyfills", [])):
        files.append(File.generated(config, DEST, abs_src_path=str(SHIM)))
    return files
