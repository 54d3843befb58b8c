"""The page `npga-view web` serves (index.html, page.js) and the pin of LAM's web player (package.json): package
data, found beside `npga_view/web_player.py`."""
