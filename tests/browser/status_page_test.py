#!/usr/bin/python3
"""The status page (issue 16 §3) in a real browser: headless Chromium driven by selenium and
chromedriver (Debian: chromium, chromium-driver, python3-selenium).

As a library, for the integration test that runs the real daemon and simulator:

    import status_page_test
    status_page_test.run(url, change_input, expected_word, fault, screenshot_path,
                         input_link='hub0', input_module='dim16 0',
                         fault_link='hub0', fault_module='dim16 0',
                         shows=[('clients', 'TLS · operator')])

run() raises PageTestFailed (an AssertionError) listing every check that failed, and returns
normally when all passed. What it checks:
  1. the page loads;
  2. the tile of input_module on input_link shows a word; change_input() is called; within
     input_timeout (5 s) the tile shows expected_word;
  3. fault() is called; within fault_timeout (10 s) the tile of fault_module on fault_link has
     a .status text other than "online";
  4. each (element id, text) of `shows`: within load_timeout the element's text contains it;
     each (link, module, text) of `tile_shows`: within load_timeout that tile's text contains it;
     the page names no user and offers no control (no user is signed in: gateway.md §7.1);
  5. the page met no violation of its Content-Security-Policy (a `securitypolicyviolation`
     event, recorded from the document's start) and the browser console has no error (level
     SEVERE: Chromium reports there what the policy refused, and a failed request); then each
     of `other_pages` (relative to url) is loaded and checked the same way;
  6. screenshots: the whole page at 1280 px wide to screenshot_path, and at 360 px wide to
     narrow_screenshot_path (default: screenshot_path with "-narrow" before the extension).
Screenshots are taken even when a check failed, to see why.

For checks of one's own, Browser() is a headless Chromium on the page with the same recorder
of policy violations (see its methods): the operator's controls are found by link, module and
point, pressed as a user does, read as the page shows them.

As a program, it runs itself against tests/browser/fixture_server.py, whose control endpoints
stand in for the simulator, and then checks an operator's controls there (gateway.md §7.1),
where the fixture can hold a write's answer, refuse it, and say what the page sent:
  - signed in as an operator, the header names the user, and dom16 0's out3 is a switch;
  - pressing it sends exactly {"link": "hub0", "module": "dom16_0", "point": "out3", "value":
    "ON"} as application/json, from the page's own origin; while the answer is held the switch
    stays off (busy) through two states, and it is on once confirmed and in the state;
  - a 200 whose value the state does not show leaves the switch as the state has it;
  - a refusal (504 no_answer) shows its text in the tile, the switch unchanged;
  - the rgbdm colour, mux8m pos and the ID-2 reset (two presses) send their bodies and show
    the confirmed value; no policy violation, no console error but the 504's;
  - as a viewer (the user's rights change under the open page, and a page loaded afresh), the
    header names the user and no control is left.

    /usr/bin/python3 tests/browser/status_page_test.py [--screenshot /tmp/status-page.png]

Exit code 0 when every check passed, 1 otherwise.
"""
import argparse
import base64
import json
import os
import re
import sys
import tempfile
import time
import urllib.parse
import urllib.request

try:
    from selenium import webdriver
    from selenium.common.exceptions import WebDriverException
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
except ImportError:  # a python3 earlier on PATH (pyenv, a venv) lacks Debian's python3-selenium
    sys.exit('status_page_test: needs selenium: run it with /usr/bin/python3 and '
             'python3-selenium installed')

CHROMEDRIVER = '/usr/bin/chromedriver'
CHROMIUM = '/usr/bin/chromium'
WIDE = (1280, 1600)
NARROW = (360, 1600)
WORD = re.compile(r'^0x[0-9A-Fa-f]{4}$')


class PageTestFailed(AssertionError):
    pass


def _selector(link, module):
    q = lambda s: '"' + s.replace('\\', '\\\\').replace('"', '\\"') + '"'
    return '[data-link=%s][data-module=%s]' % (q(link), q(module))


# Reads by selector on every poll rather than holding element references: the page may rebuild
# its tiles (after a reload of the daemon's configuration), which would make them stale.
_TILE_TEXT = """
const tile = document.querySelector(arguments[0]);
if (!tile) return null;
const e = tile.querySelector(arguments[1]);
return e ? e.textContent.trim() : '';
"""
_WHOLE_TILE_TEXT = """
const tile = document.querySelector(arguments[0]);
return tile ? tile.textContent : null;
"""
_ELEMENT_TEXT = """
const e = document.getElementById(arguments[0]);
return e ? e.textContent.trim() : null;
"""
_TILES = """
return [...document.querySelectorAll('[data-module]')]
  .map(t => t.dataset.link + ' / ' + t.dataset.module);
"""
# Anything a user could act with: the page has no form, so any of these is a write control.
_CONTROLS = """
return [...document.querySelectorAll(
    'button, input, select, textarea, [role=switch], [data-point], [contenteditable]')]
  .map(e => e.outerHTML.slice(0, 120));
"""
_USER = """
const e = document.getElementById('user');
return e && !e.hidden ? e.textContent.trim() : null;
"""
# A control as the page shows it; null when there is none.
_CONTROL = """
const e = document.querySelector(arguments[0]);
return e && {checked: e.getAttribute('aria-checked'), pressed: e.getAttribute('aria-pressed'),
             busy: e.getAttribute('aria-busy') === 'true', disabled: e.disabled,
             text: e.textContent.trim()};
"""


def _wait(what, timeout, probe):
    """Polls probe() until it returns something other than None, or the deadline passes.
    Returns (value, seconds taken); raises PageTestFailed naming `what` on timeout."""
    start = time.monotonic()
    deadline = start + timeout
    while True:
        value = probe()
        if value is not None:
            return value, time.monotonic() - start
        if time.monotonic() >= deadline:
            raise PageTestFailed('%s: not within %.1f s' % (what, timeout))
        time.sleep(0.1)


class _Page:
    def __init__(self, driver):
        self.driver = driver

    def text(self, link, module, cls):
        """The text of the .cls element of a tile; None if there is no such tile, '' if the
        tile has no such element."""
        return self.driver.execute_script(_TILE_TEXT, _selector(link, module), '.' + cls)

    def tile_text(self, link, module):
        """All the text of a tile; None if there is no such tile."""
        return self.driver.execute_script(_WHOLE_TILE_TEXT, _selector(link, module))

    def require_tile(self, link, module, timeout):
        try:
            _wait('tile %s / %s appears' % (link, module), timeout,
                  lambda: True if self.text(link, module, 'status') is not None else None)
        except PageTestFailed as e:
            tiles = self.driver.execute_script(_TILES)
            raise PageTestFailed('%s; the page has these tiles: %s'
                                 % (e, ', '.join(tiles) or 'none')) from None

    def word(self, link, module):
        t = self.text(link, module, 'word')
        return int(t, 16) if t and WORD.match(t) else None

    def banner(self):
        return self.driver.execute_script(
            "const e = document.getElementById('conn'); return e ? e.textContent.trim() : '';")

    def screenshot(self, path, size):
        """The whole page, not only the window, at the given window width."""
        self.driver.set_window_size(*size)
        _wait('the window is %d px wide' % size[0], 5,
              lambda: True if self.driver.execute_script('return window.innerWidth') <= size[0]
              else None)
        # The reflow at the new width is done once two animation frames have been drawn.
        self.driver.execute_async_script(
            'const done = arguments[0]; requestAnimationFrame(() => requestAnimationFrame(done));')
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        try:
            m = self.driver.execute_cdp_cmd('Page.getLayoutMetrics', {})
            content = m.get('cssContentSize') or m['contentSize']
            shot = self.driver.execute_cdp_cmd('Page.captureScreenshot', {
                'format': 'png', 'captureBeyondViewport': True,
                'clip': {'x': 0, 'y': 0, 'width': content['width'],
                         'height': content['height'], 'scale': 1}})
            with open(path, 'wb') as f:
                f.write(base64.b64decode(shot['data']))
        except (WebDriverException, KeyError):
            self.driver.save_screenshot(path)  # the window only, but something to look at


# Installed before any of the page's own code runs in every document the browser loads, so that
# a violation in the document's markup (an inline script, a style attribute) is caught too.
_CSP_RECORDER = """
window.__cspViolations = [];
document.addEventListener('securitypolicyviolation', e => window.__cspViolations.push(
  e.effectiveDirective + ' refused ' + (e.blockedURI || 'inline code') + ' at ' +
  e.sourceFile + ':' + e.lineNumber));
"""


def problems(driver, allowed=()):
    """What the browser refused or complained about: the current document's violations of its
    Content-Security-Policy not yet reported, and the console's errors (level SEVERE) since the
    last call but those matching one of the regular expressions `allowed`."""
    violations = driver.execute_script(
        'return window.__cspViolations ? window.__cspViolations.splice(0) : null')
    if violations is None:
        return ['the recorder of Content-Security-Policy violations did not run in %s'
                % driver.current_url]
    found = ['Content-Security-Policy: %s' % v for v in violations]
    for entry in driver.get_log('browser'):
        message = entry.get('message', '')
        if entry.get('level') == 'SEVERE' and not any(re.search(a, message) for a in allowed):
            found.append('console: %s' % message)
    return found


def _driver(profile):
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for a in ('--headless=new', '--no-sandbox', '--disable-gpu', '--disable-dev-shm-usage',
              '--disable-background-networking', '--disable-component-update', '--disable-sync',
              '--no-first-run', '--user-data-dir=' + profile,
              '--window-size=%d,%d' % WIDE):
        options.add_argument(a)
    options.set_capability('goog:loggingPrefs', {'browser': 'ALL'})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.execute_cdp_cmd('Page.addScriptToEvaluateOnNewDocument', {'source': _CSP_RECORDER})
    return driver


def run(url, change_input, expected_word, fault, screenshot_path, *,
        input_link='hub0', input_module='dim16 0', fault_link='hub0', fault_module='dim16 0',
        shows=(), tile_shows=(), other_pages=(), narrow_screenshot_path=None, load_timeout=15.0,
        input_timeout=5.0, fault_timeout=10.0):
    """Checks the status page at `url` in headless Chromium (see the module's docstring).

    change_input(): makes the input word of input_module on input_link become expected_word
    (an int, 0..0xFFFF) at the device; fault(): makes fault_module on fault_link stop answering
    (or answer badly). Both are called once, in that order. Raises PageTestFailed listing the
    failed checks."""
    if narrow_screenshot_path is None:
        base, ext = os.path.splitext(screenshot_path)
        narrow_screenshot_path = base + '-narrow' + (ext or '.png')
    failures = []

    def check(name, fn):
        print('status_page_test: %s ...' % name, flush=True)
        try:
            fn()
        except PageTestFailed as e:
            print('status_page_test: FAIL: %s' % e, flush=True)
            failures.append(str(e))
            return False
        return True

    with tempfile.TemporaryDirectory(prefix='status-page-test-') as profile:
        driver = _driver(profile)
        try:
            page = _Page(driver)
            driver.set_page_load_timeout(load_timeout)

            def load():
                try:
                    driver.get(url)
                except WebDriverException as e:
                    raise PageTestFailed('cannot load %s: %s' % (url, e.msg)) from None
                title = driver.title
                if 'ioportd' not in title:
                    raise PageTestFailed('%s has the title %r, not the status page' % (url, title))

            def input_changes():
                page.require_tile(input_link, input_module, load_timeout)
                before, took = _wait('tile %s / %s shows a word (.word as 0xHHHH)'
                                     % (input_link, input_module), load_timeout,
                                     lambda: page.word(input_link, input_module))
                print('status_page_test: %s / %s shows 0x%04X after %.1f s'
                      % (input_link, input_module, before, took), flush=True)
                banner = page.banner()
                if banner:
                    raise PageTestFailed('the page shows data and yet says: %r' % banner)
                if before == expected_word:
                    raise PageTestFailed('%s / %s already shows the expected word 0x%04X before '
                                         'change_input(): the check would prove nothing'
                                         % (input_link, input_module, expected_word))
                change_input()
                last = [before]

                def changed():
                    last[0] = page.word(input_link, input_module)
                    return True if last[0] == expected_word else None
                try:
                    _, took = _wait('after change_input(), tile %s / %s shows 0x%04X'
                                    % (input_link, input_module, expected_word),
                                    input_timeout, changed)
                except PageTestFailed as e:
                    shown = 'nothing' if last[0] is None else '0x%04X' % last[0]
                    raise PageTestFailed('%s (it shows %s)' % (e, shown)) from None
                print('status_page_test: %s / %s shows 0x%04X %.1f s after change_input()'
                      % (input_link, input_module, expected_word, took), flush=True)

            def fault_shows():
                page.require_tile(fault_link, fault_module, load_timeout)
                fault()
                last = ['']

                def not_online():
                    last[0] = page.text(fault_link, fault_module, 'status')
                    return last[0] if last[0] and last[0] != 'online' else None
                try:
                    status, took = _wait('after fault(), tile %s / %s has a .status other than '
                                         '"online"' % (fault_link, fault_module),
                                         fault_timeout, not_online)
                except PageTestFailed as e:
                    raise PageTestFailed('%s (it says %r)' % (e, last[0])) from None
                print('status_page_test: %s / %s says %r %.1f s after fault()'
                      % (fault_link, fault_module, status, took), flush=True)

            def element_shows(element, text):
                last = [None]

                def contains():
                    last[0] = driver.execute_script(_ELEMENT_TEXT, element)
                    return True if last[0] and text in last[0] else None
                try:
                    _wait('#%s shows %r' % (element, text), load_timeout, contains)
                except PageTestFailed as e:
                    raise PageTestFailed('%s (it shows %r)' % (e, last[0])) from None

            def offers_nothing():
                controls = driver.execute_script(_CONTROLS)
                user = driver.execute_script(_USER)
                if controls or user is not None:
                    raise PageTestFailed('with no user signed in, the page names %r and offers '
                                         '%d control(s): %s' % (user, len(controls),
                                                                '; '.join(controls[:5])))

            def tile_shows_text(link, module, text):
                last = [None]

                def contains():
                    last[0] = page.tile_text(link, module)
                    return True if last[0] and text in last[0] else None
                try:
                    _wait('tile %s / %s shows %r' % (link, module, text), load_timeout, contains)
                except PageTestFailed as e:
                    raise PageTestFailed('%s (it shows %r)' % (e, last[0])) from None

            def clean(where):
                found = problems(driver)
                if found:
                    raise PageTestFailed('%s: %d problem(s):\n  %s'
                                         % (where, len(found), '\n  '.join(found)))

            def other_page_clean(path):
                target = urllib.parse.urljoin(url, path)
                try:
                    driver.get(target)
                except WebDriverException as e:
                    raise PageTestFailed('cannot load %s: %s' % (target, e.msg)) from None
                clean(target)

            def screenshots():
                for path, size in ((screenshot_path, WIDE), (narrow_screenshot_path, NARROW)):
                    page.screenshot(path, size)
                    print('status_page_test: screenshot %s (%d px wide)' % (path, size[0]),
                          flush=True)

            if check('load %s' % url, load):
                check('an input change reaches the page', input_changes)
                check('a module fault reaches the page', fault_shows)
                for element, text in shows:
                    check('#%s shows %r' % (element, text),
                          lambda element=element, text=text: element_shows(element, text))
                for link, module, text in tile_shows:
                    check('tile %s / %s shows %r' % (link, module, text),
                          lambda link=link, module=module, text=text:
                          tile_shows_text(link, module, text))
                check('no user named, no control offered', offers_nothing)
            check('no policy violation, no error in the browser console', lambda: clean(url))
            check('screenshots', screenshots)
            for path in other_pages:
                check('%s: no policy violation, no error in the browser console' % path,
                      lambda path=path: other_page_clean(path))
        finally:
            driver.quit()
    if failures:
        raise PageTestFailed('%d check(s) failed:\n- %s' % (len(failures), '\n- '.join(failures)))
    print('status_page_test: all checks passed', flush=True)


class Browser:
    """A headless Chromium of one's own, with the policy-violation recorder of run():

        with Browser() as b:
            b.open(url)
            b.wait_control('out3 is off', 'hub0', 'dom16 0', 'out3', checked='false')
            b.press('hub0', 'dom16 0', 'out3')
    """

    def __enter__(self):
        self._profile = tempfile.TemporaryDirectory(prefix='status-page-test-')
        self.driver = _driver(self._profile.name)
        self.page = _Page(self.driver)
        return self

    def __exit__(self, *exc):
        self.driver.quit()
        self._profile.cleanup()

    def open(self, url, timeout=15.0, status_page=True):
        self.driver.set_page_load_timeout(timeout)
        try:
            self.driver.get(url)
        except WebDriverException as e:
            raise PageTestFailed('cannot load %s: %s' % (url, e.msg)) from None
        if status_page and 'ioportd' not in self.driver.title:
            raise PageTestFailed('%s has the title %r, not the status page'
                                 % (url, self.driver.title))

    @staticmethod
    def _control_selector(link, module, point, value):
        return '%s [data-point="%s"]%s' % (_selector(link, module), point,
                                           '' if value is None else '[data-value="%s"]' % value)

    def control(self, link, module, point, value=None):
        """{checked, pressed, busy, disabled, text} of a control as the page shows it (checked
        and pressed: its aria-checked and aria-pressed); None when there is no such control."""
        return self.driver.execute_script(_CONTROL,
                                          self._control_selector(link, module, point, value))

    def wait_control(self, what, link, module, point, value=None, timeout=5.0, **expected):
        """Until the control's fields have the `expected` values; raises naming `what`."""
        last = [None]

        def matches():
            last[0] = self.control(link, module, point, value)
            return True if last[0] and all(last[0].get(k) == v for k, v in expected.items()) \
                else None
        try:
            _wait(what, timeout, matches)
        except PageTestFailed as e:
            raise PageTestFailed('%s (it is %r)' % (e, last[0])) from None

    def press(self, link, module, point, value=None):
        """A click on the control, as a user's: scrolled into view, at its middle."""
        selector = self._control_selector(link, module, point, value)
        try:
            self.driver.find_element(By.CSS_SELECTOR, selector).click()
        except WebDriverException as e:
            raise PageTestFailed('cannot press %s: %s' % (selector, e.msg)) from None

    def refusal(self, link, module):
        """The refusal the tile shows ('' when none)."""
        return self.driver.execute_script(
            "const e = document.querySelector(arguments[0]);"
            "return e && !e.hidden ? e.textContent.trim() : '';",
            _selector(link, module) + ' .refusal')

    def text(self, link, module, cls):
        return self.page.text(link, module, cls)

    def controls(self):
        """Every control on the page, as the start of its markup."""
        return self.driver.execute_script(_CONTROLS)

    def user(self):
        """The header's "signed in as …", None when it names no one."""
        return self.driver.execute_script(_USER)

    def renders(self, count, timeout=10.0):
        """Waits until the page has shown `count` states more (its "updated" time moved on)."""
        seen = [self.driver.execute_script(_ELEMENT_TEXT, 'updated')]

        def moved():
            now = self.driver.execute_script(_ELEMENT_TEXT, 'updated')
            if now != seen[-1]:
                seen.append(now)
            return True if len(seen) > count else None
        _wait('%d more state(s) shown' % count, timeout, moved)

    def clean(self, where, allowed=()):
        found = problems(self.driver, allowed)
        if found:
            raise PageTestFailed('%s: %d problem(s):\n  %s' % (where, len(found),
                                                                 '\n  '.join(found)))

    def screenshot(self, path, size=WIDE):
        self.page.screenshot(path, size)


def wait_user(browser, text, timeout=15.0):
    last = [None]

    def shows():
        last[0] = browser.user()
        return True if last[0] == text else None
    try:
        _wait('the header says %r' % text, timeout, shows)
    except PageTestFailed as e:
        raise PageTestFailed('%s (it says %r)' % (e, last[0])) from None


def wait_no_controls(browser, timeout=15.0):
    last = [None]

    def none():
        last[0] = browser.controls()
        return True if not last[0] else None
    try:
        _wait('no control on the page', timeout, none)
    except PageTestFailed as e:
        raise PageTestFailed('%s (it has %d: %s)' % (e, len(last[0]), '; '.join(last[0][:5]))) \
            from None


# ---- Self-test against the fixture server ------------------------------------------------------

def _post(base, action, **query):
    url = urllib.parse.urljoin(base, 'control/%s?%s' % (action, urllib.parse.urlencode(query)))
    with urllib.request.urlopen(urllib.request.Request(url, data=b'', method='POST'),
                                timeout=5) as r:
        return json.load(r)


def _operator_self_test(url, screenshot_path):
    """The operator's controls against the fixture (see the module's docstring); the failures."""
    post = lambda action, **q: _post(url, action, **q)  # noqa: E731
    origin = '{0.scheme}://{0.netloc}'.format(urllib.parse.urlsplit(url))
    post('scada', on='0')  # its writes to dom16 0 would flip out3 by themselves
    post('input', link='hub0', module='dom16 0', word='0x0000')
    post('user', name='alice', operator='1')
    post('writes', clear='1')
    failures = []

    def check(name, fn):
        print('status_page_test: %s ...' % name, flush=True)
        try:
            fn()
        except PageTestFailed as e:
            print('status_page_test: FAIL: %s' % e, flush=True)
            failures.append(str(e))

    def sent(body):
        """The one write the fixture got since the last call: exactly `body`, as JSON."""
        writes, _ = _wait('the fixture gets the write %s' % json.dumps(body), 10,
                          lambda: post('writes', clear='1') or None)
        expected = {'content_type': 'application/json', 'origin': origin,
                    'body': json.dumps(body, separators=(',', ':'))}
        if writes != [expected]:
            raise PageTestFailed('the page sent %r, not %r' % (writes, [expected]))

    with Browser() as b:
        def signed_in():
            b.open(url)
            wait_user(b, 'signed in as alice')
            b.wait_control('dom16 0 out3 is a switch, off', 'hub0', 'dom16 0', 'out3',
                           timeout=15, checked='false', busy=False, disabled=False)

        def switched_once_confirmed():
            post('hold', on='1')
            try:
                b.press('hub0', 'dom16 0', 'out3')
                sent({'link': 'hub0', 'module': 'dom16_0', 'point': 'out3', 'value': 'ON'})
                b.renders(2)
                shown = b.control('hub0', 'dom16 0', 'out3')
                if shown != dict(shown or {}, checked='false', busy=True):
                    raise PageTestFailed('out3 shows %r before the device confirmed it, not '
                                         'off and busy' % shown)
            finally:
                post('hold', on='0')
            b.wait_control('out3 is on once confirmed', 'hub0', 'dom16 0', 'out3',
                           checked='true', busy=False)

        def the_state_decides():
            post('answer', status='200', result='confirmed')  # the state will not show it
            b.press('hub0', 'dom16 0', 'out5')
            sent({'link': 'hub0', 'module': 'dom16_0', 'point': 'out5', 'value': 'ON'})
            b.wait_control('out5 is no longer busy', 'hub0', 'dom16 0', 'out5', busy=False)
            b.renders(1)
            shown = b.control('hub0', 'dom16 0', 'out5')
            if shown['checked'] != 'false':
                raise PageTestFailed('out5 shows %r where the state has it off' % shown)

        def refusal_shows():
            why = 'link hub0: dom16 0 did not answer within 50 ms'
            post('answer', status='504', result='no_answer', error=why)
            b.press('hub0', 'dom16 0', 'out3')
            sent({'link': 'hub0', 'module': 'dom16_0', 'point': 'out3', 'value': 'OFF'})
            text, _ = _wait('the tile shows the refusal', 5,
                            lambda: b.refusal('hub0', 'dom16 0') or None)
            if why not in text or 'no_answer' not in text:
                raise PageTestFailed('the tile says %r, not the refusal %r' % (text, why))
            b.wait_control('out3 stays on, not busy', 'hub0', 'dom16 0', 'out3',
                           checked='true', busy=False)

        def other_points():
            b.press('hub0', 'rgbdm 0', 'colour', 'blue')
            sent({'link': 'hub0', 'module': 'rgbdm_0', 'point': 'colour', 'value': 'blue'})
            b.wait_control('blue is the colour', 'hub0', 'rgbdm 0', 'colour', 'blue',
                           pressed='true', busy=False)
            b.press('hub0', 'mux8m 0', 'pos', '3')
            sent({'link': 'hub0', 'module': 'mux8m_0', 'point': 'pos', 'value': '3'})
            b.wait_control('pos is 3', 'hub0', 'mux8m 0', 'pos', '3', pressed='true', busy=False)
            b.press('press', 'ID-2', 'reset')
            b.wait_control('the reset asks to be pressed again', 'press', 'ID-2', 'reset',
                           text='press again to reset the count')
            b.press('press', 'ID-2', 'reset')
            sent({'link': 'press', 'module': 'id2', 'point': 'reset', 'value': 'ON'})
            # The page writes 4,898 for 4898.
            _wait('the count starts again', 5, lambda: True if int(
                (b.text('press', 'ID-2', 'count') or '9999').replace(',', '')) < 100 else None)

        def clean():
            b.clean(url, allowed=[r'api/v1/write - Failed to load resource: the server '
                                  r'responded with a status of 504'])

        def viewer():
            post('user', name='bob', operator='0')
            wait_user(b, 'signed in as bob (read only)')
            wait_no_controls(b)
            b.open(url)
            wait_user(b, 'signed in as bob (read only)')
            b.renders(1)
            wait_no_controls(b, timeout=0)
            b.clean(url)

        check('signed in as an operator, out3 is a switch', signed_in)
        if not failures:
            check('out3 switches on once the device confirmed it', switched_once_confirmed)
            check('a confirmation alone does not change a switch', the_state_decides)
            check('a refusal shows in words', refusal_shows)
            check('colour, pos and the ID-2 reset', other_points)
            check('no policy violation, no console error but the refusal', clean)
            check('screenshot', lambda: b.screenshot(screenshot_path))
        check('a viewer gets no control', viewer)
    return failures


def main():
    ap = argparse.ArgumentParser(description='The status page in headless Chromium, against '
                                 'tests/browser/fixture_server.py.')
    ap.add_argument('--url', help='a fixture server already running, e.g. '
                    'http://127.0.0.1:8080/ioportd/ (default: start one on a free port)')
    ap.add_argument('--screenshot', default=os.path.join(tempfile.gettempdir(),
                                                         'status-page.png'))
    ap.add_argument('--narrow-screenshot', help='default: SCREENSHOT with -narrow')
    args = ap.parse_args()

    url = args.url
    server = None
    if not url:
        sys.dont_write_bytecode = True  # no __pycache__ in the source tree
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        import fixture_server
        server = fixture_server.serve()
        # Under a path, as behind a reverse proxy: the page must use relative URLs only.
        url = 'http://127.0.0.1:%d%s/' % (server.server_address[1], fixture_server.PREFIX)
    if not url.endswith('/'):
        url += '/'

    link, module = 'hub0', 'dim16 0'
    word = _post(url, 'input', link=link, module=module, word='0x0005')['word']
    expected = word ^ 0x0008  # input 3 flips
    try:
        run(url,
            change_input=lambda: _post(url, 'input', link=link, module=module,
                                       word='0x%04X' % expected),
            expected_word=expected,
            fault=lambda: _post(url, 'fault', link='hub0', module='acm3p 0', status='2'),
            shows=[('clients', 'TLS · operator'), ('clients', 'plain TCP'), ('mb-th', '2'),
                   ('mb-listen', '0.0.0.0:802 (TLS)')],
            tile_shows=[('hub0', 'acm3p 0', 'boiler 1'), ('hub0', 'acm3p 0', 'supply'),
                        ('hub0', 'dim16 0', 'pump running')],
            screenshot_path=args.screenshot, narrow_screenshot_path=args.narrow_screenshot,
            input_link=link, input_module=module, fault_link='hub0', fault_module='acm3p 0')
        base, ext = os.path.splitext(args.screenshot)
        failures = _operator_self_test(url, base + '-operator' + (ext or '.png'))
        if failures:
            raise PageTestFailed('%d operator check(s) failed:\n- %s'
                                 % (len(failures), '\n- '.join(failures)))
    except PageTestFailed as e:
        print('status_page_test: FAILED\n%s' % e, file=sys.stderr)
        return 1
    finally:
        if server:
            server.shutdown()
    print('status_page_test: the operator checks passed', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
