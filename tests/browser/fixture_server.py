#!/usr/bin/python3
"""A stand-in for ioportd's HTTP API (issue 16), so the status page can be developed and tested
without the daemon: it serves daemon/http/status_page/ (index.html at /, app.js, app.css,
icon.svg) under the daemon's Content-Security-Policy, and JSON that follows docs/http.md
(GET api/v1/state, GET api/v1/trends), with values that move.

Everything is also served under /ioportd/, to check that the page only uses relative URLs, as
it must behind a reverse proxy.

It also takes POST api/v1/write (gateway.md §7.1) from the page of an operator: it records
what it got (content type, Origin, the body as sent), and answers it with the next canned answer
if there is one, else as the daemon does once the device confirmed: 200 {"result": "confirmed"},
the value in the state from then on.

Control endpoints, for the browser self-test only (the real daemon has none of them):
    POST /control/input?link=hub0&module=dim16%200&word=0x0008   set an input (or output) word
    POST /control/fault?link=hub0&module=acm3p%200&status=2      2 no answer, 3 bad answer, 1 back
    POST /control/port?link=hub1&open=1                          port open / not open
    POST /control/comm_loss?on=1                                 the Modbus server's comm loss
    POST /control/outage?seconds=5                               the API drops every request
    POST /control/user?name=alice&operator=1                     the state's user (no name: null)
    POST /control/scada?on=0                                     stop the imaginary SCADA's writes
                                                                 to dom16 0 (every 7 s)
    POST /control/hold?on=1                                      writes wait for hold?on=0
    POST /control/answer?status=504&result=no_answer&error=...   the next write's answer
    POST /control/writes?clear=1                                 the writes received, oldest first
Each answers what changed as JSON.

Python 3 standard library only. Usage: fixture_server.py [--port 8080] [--host 127.0.0.1]
"""
import argparse
import datetime
import json
import math
import os
import re
import threading
import time
import urllib.parse
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

PAGE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..',
                        'daemon', 'http', 'status_page')
# The files of the page by path, as daemon/http/http_route.cpp routes them and render.cpp
# types them.
ASSETS = {'/': ('index.html', 'text/html; charset=utf-8'),
          '/app.js': ('app.js', 'text/javascript; charset=utf-8'),
          '/app.css': ('app.css', 'text/css; charset=utf-8'),
          '/icon.svg': ('icon.svg', 'image/svg+xml')}
# As daemon/http/http_server.cpp sends them (gateway.md §7.1): the page must work under them.
SECURITY_HEADERS = {'Content-Security-Policy': "default-src 'self'; frame-ancestors 'none'",
                    'Referrer-Policy': 'no-referrer', 'X-Content-Type-Options': 'nosniff'}
PREFIX = '/ioportd'  # the same site under a path, as behind a reverse proxy
STATUS_TEXT = {1: 'online', 2: 'no answer', 3: 'bad answer', 4: 'not polled yet'}
SWITCH = {'ON': 1, 'on': 1, '1': 1, 'true': 1, 'OFF': 0, 'off': 0, '0': 0, 'false': 0}
COLOURS = ['off', 'red', 'green', 'blue', 'cyan', 'magenta', 'yellow', 'white']
FULL_SCALE = {'acm3p': (100.0, '%'), 'acm3c': (100.0, '%'), 'dccim': (6.0, 'A'),
              'dcvim': (32.0, 'V')}
TREND_INTERVAL = 5
TREND_SPAN = 600


def rfc3339(t):
    d = datetime.datetime.fromtimestamp(t, datetime.timezone.utc)
    return d.strftime('%Y-%m-%dT%H:%M:%S.') + '%03dZ' % (d.microsecond // 1000)


def analog(type_, number, channel, t):
    """The engineering value of an analog channel at time t: slow waves, distinct per channel,
    so a trend plot has something to show; a pure function of t, so the trends need no store."""
    full, _ = FULL_SCALE[type_]
    phase = number * 1.3 + channel * 2.1
    if type_ == 'dccim':  # a loop current around 2.4 A
        return 2.4 + 0.35 * math.sin(t / 47 + phase) + 0.05 * math.sin(t / 3.1)
    if type_ == 'dcvim':  # a 24 V supply with a little ripple
        return 24.0 + 0.3 * math.sin(t / 83 + phase) + 0.04 * math.sin(t / 2.3)
    base = (35, 60, 20)[channel % 3]
    return min(full, max(0.0, base + 18 * math.sin(t / (60 + 25 * channel) + phase)
                         + 3 * math.sin(t / 7.7 + phase)))


class Module:
    def __init__(self, type_, number, slot, **values):
        self.type = type_
        self.number = number
        self.id = 'id2' if type_ == 'id2' else '%s_%d' % (type_, number)  # gateway.md §6.3
        self.slot = slot
        self.name = 'ID-2' if type_ == 'id2' else '%s %d' % (type_, number)
        self.status = values.pop('status', 1)
        self.offline_since = None if self.status == 1 else time.time()
        self.last_good = time.time() if self.status == 1 else None
        self.values = values

    def json(self, now):
        # Names as gateway.md §6.1 configures them: acm3p 0 and its channel 0, inputs of dim16 0.
        named = self.type == 'acm3p' and self.number == 0
        m = {'module': self.name, 'name': 'boiler 1' if named else self.name,
             'type': self.type, 'number': self.number, 'slot': self.slot,
             'status': self.status, 'status_text': STATUS_TEXT[self.status],
             'age_seconds': None if self.last_good is None else round(now - self.last_good, 3)}
        if self.type in FULL_SCALE:
            full, unit = FULL_SCALE[self.type]
            count = 3 if self.type in ('acm3p', 'acm3c') else 1
            m['channels'] = []
            for c in range(count):
                raw = None if self.last_good is None else round(
                    analog(self.type, self.number, c, self.last_good) / full * 65535)
                m['channels'].append({'raw': raw, 'value': None if raw is None else raw / 65535 * full,
                                      'unit': unit, 'name': 'supply' if named and c == 0 else '',
                                      'range': [0, full], 'scale': None})
        elif self.type == 'rgbdm':
            c = self.values['colour']
            m['colour'] = c
            m['colour_name'] = COLOURS[c] if c is not None else None
        else:  # what the fixture keeps for itself aside
            m.update({k: v for k, v in self.values.items() if k not in ('step', 'reset_at')})
            if self.type in ('dim16', 'lim16', 'dom16'):
                points = {'0': 'door open', '3': 'pump running'} if self.type == 'dim16' else {}
                m['outputs' if self.type == 'dom16' else 'inputs'] = points
        return m


class Fixture:
    """The gateway's state; every access holds self.lock."""

    def __init__(self):
        self.lock = threading.Lock()
        self.answered = threading.Condition(self.lock)  # a held write waits on it
        self.user = None  # the state's "user": null, as without authentication
        self.scada = True
        self.held = False
        self.answers = []  # canned (status, answer) for the next writes
        self.writes = []  # what the page sent
        self.started = time.time() - 11045  # as if up for 3 h: a full 10 min of trends
        self.outage_until = 0.0
        self.seq = 0
        self.events = []
        self.links = [
            {'name': 'hub0', 'protocol': 'ioport', 'device': '/dev/ttyUSB0', 'baud': 115200,
             'unit_id': 1, 'port_open': True, 'reopens': 0, 'ok': 0, 'no_answer': 0,
             'bad_answer': 0, 'error_ack': 0,
             'writes': {'confirmed': 3, 'error_ack': 0, 'no_answer': 0, 'link_down': 0, 'busy': 0, 'dropped': 0},
             'modules': [
                 Module('dim16', 0, 0, word=0x0005),
                 Module('dom16', 0, 1, word=0x0000),
                 Module('acm3p', 0, 2),
                 Module('lim16', 0, 3, word=0x8001),
                 Module('rgbdm', 0, 4, colour=2),
                 Module('mux8m', 0, 5, pos=1, neg=2),
                 Module('dccim', 0, 6),
                 Module('dcvim', 0, 7),
                 Module('acm3c', 0, 8)]},
            {'name': 'press', 'protocol': 'id2', 'device': '/dev/ttyS1', 'baud': 9600,
             'unit_id': 2, 'port_open': True, 'reopens': 0, 'ok': 0, 'no_answer': 0,
             'bad_answer': 0, 'error_ack': 0,
             'writes': {'confirmed': 0, 'error_ack': 0, 'no_answer': 0, 'link_down': 0, 'busy': 0, 'dropped': 0},
             'modules': [Module('id2', 0, 0, stop=False, count=1207)]},
            {'name': 'hub1', 'protocol': 'ioport', 'device': '/dev/ttyUSB1', 'baud': 38400,
             'unit_id': 3, 'port_open': False, 'reopens': 4, 'ok': 0, 'no_answer': 0,
             'bad_answer': 0, 'error_ack': 0,
             'writes': {'confirmed': 0, 'error_ack': 0, 'no_answer': 0, 'link_down': 2, 'busy': 0, 'dropped': 0},
             'modules': [Module('dim16', 1, 0, word=None, status=4),
                         Module('dom16', 1, 1, word=None, status=4)]},
        ]
        self.clients = [{'address': '10.0.0.5:50123', 'since': time.time() - 3725, 'requests': 0,
                         'transport': 'tcp', 'role': ''},
                        {'address': '10.0.0.17:41002', 'since': time.time() - 42, 'requests': 0,
                         'transport': 'tls', 'role': 'operator'}]
        self.refused = {'not_allowed': 0, 'too_many': 1, 'tls_handshake': 2,
                        'too_many_handshakes': 0}
        self.comm_loss = False
        self.last_tick = time.time()
        self.event('reload', '', '', '', 'ioportd 0.1.0 started with 3 links, 12 modules')
        for link in self.links:
            for m in link['modules']:
                if m.status == 1:
                    self.event('module_online', link['name'], m.name, '',
                               'link %s: %s online' % (link['name'], m.name))
        self.event('port_down', 'hub1', '', '',
                   'link hub1: /dev/ttyUSB1: cannot open: No such file or directory')
        self.event('client_refused', '', '', '192.0.2.9:40112',
                   'modbus: refused 192.0.2.9:40112: too many connections (32)')

    def event(self, kind, link, module, client, text):
        self.seq += 1
        self.events.append({'seq': self.seq, 'time': rfc3339(time.time()), 'kind': kind,
                            'link': link, 'module': module, 'client': client, 'text': text})
        del self.events[:-100]

    def find(self, link_name, module_name=None):
        for link in self.links:
            if link['name'] == link_name:
                if module_name is None:
                    return link
                for m in link['modules']:
                    if m.name == module_name:
                        return m
        raise KeyError('no %s on link %s' % (module_name or 'link', link_name))

    def tick(self):
        """Advances the simulated gateway to now: counters, the outputs that an imaginary SCADA
        writes every 7 s, an ID-2 that counts parts."""
        now = time.time()
        cycles = int((now - self.last_tick) / 0.05)
        if cycles <= 0:
            return now
        self.last_tick = now
        for link in self.links:
            if not link['port_open']:
                continue
            for m in link['modules']:
                if m.status == 1:
                    link['ok'] += cycles
                    m.last_good = now
                elif m.status == 2:
                    link['no_answer'] += cycles
                elif m.status == 3:
                    link['bad_answer'] += cycles
        for c in self.clients:
            c['requests'] += cycles * 2
        step = int(now // 7)
        dom = self.find('hub0', 'dom16 0')
        if self.scada and dom.status == 1 and dom.values.get('step') != step:
            dom.values['step'] = step
            dom.values['word'] = (0x0101 << (step % 8)) & 0xFFFF
            self.find('hub0')['writes']['confirmed'] += 1
            self.event('write', 'hub0', 'dom16 0', '10.0.0.5:50123',
                       'link hub0: dom16 0 <- 0x%04X confirmed' % dom.values['word'])
        lim = self.find('hub0', 'lim16 0')
        if lim.status == 1:
            lim.values['word'] = 0x8001 | (0x0010 if int(now // 11) % 2 else 0)
        id2 = self.find('press', 'ID-2')
        counted_from = id2.values.get('reset_at')
        id2.values['count'] = (int(now - counted_from) // 3 if counted_from
                               else 1207 + int(now - self.started) // 3)
        id2.values['stop'] = int(now // 30) % 4 == 0
        return now

    def state(self):
        now = self.tick()
        links = []
        for link in self.links:
            active = [m for m in link['modules']]
            links.append({
                'name': link['name'], 'protocol': link['protocol'], 'device': link['device'],
                'baud': link['baud'], 'unit_id': link['unit_id'], 'port_open': link['port_open'],
                'cycle_seconds': (0.0118 + 0.0007 * math.sin(now) if link['protocol'] == 'ioport'
                                  else 0.0412) if link['port_open'] else None,
                'transactions': {k: link[k] for k in ('ok', 'no_answer', 'bad_answer',
                                                      'error_ack')},
                'reopens': link['reopens'], 'writes': dict(link['writes']),
                'modules': [m.json(now) for m in active]})
        ok = all(l['port_open'] for l in self.links if l['name'] != 'hub1')
        return {
            'version': '0.1.0', 'time': rfc3339(now), 'started': rfc3339(self.started),
            'user': self.user,
            'health': {'ok': ok, 'reason': '' if ok else 'a link is down'},
            'warnings': [],
            'modbus': {'listen': '0.0.0.0:502', 'tls_listen': '0.0.0.0:802',
                       'connections': len(self.clients), 'handshakes': 0,
                       'max_connections': 32, 'comm_loss': self.comm_loss,
                       'refused': dict(self.refused),
                       'clients': [{'address': c['address'], 'since': rfc3339(c['since']),
                                    'requests': c['requests'], 'transport': c['transport'],
                                    'role': c['role']} for c in self.clients]},
            'links': links,
            'events': list(self.events)}

    def trends(self):
        now = self.tick()
        series = []
        end = int(now // TREND_INTERVAL) * TREND_INTERVAL
        for link in self.links:
            for m in link['modules']:
                if m.type not in FULL_SCALE or m.last_good is None:
                    continue
                full, unit = FULL_SCALE[m.type]
                # One point per interval while the module answered; none while it did not.
                first = max(end - TREND_SPAN + TREND_INTERVAL, int(self.started) - 3600)
                stop = m.offline_since if m.status != 1 else now
                for c in range(3 if m.type in ('acm3p', 'acm3c') else 1):
                    pts = [[t, round(analog(m.type, m.number, c, t), 4)]
                           for t in range(first, end + 1, TREND_INTERVAL) if t <= stop]
                    series.append({'link': link['name'], 'module': m.name, 'channel': c,
                                   'unit': unit, 'points': pts[-120:]})
        return {'interval_seconds': TREND_INTERVAL, 'span_seconds': TREND_SPAN, 'series': series}

    def control(self, action, q):
        """The self-test's levers; returns what changed."""
        if action == 'input':
            m = self.find(q['link'], q['module'])
            m.values['word'] = int(q['word'], 0) & 0xFFFF
            return m.json(time.time())
        if action == 'fault':
            m = self.find(q['link'], q['module'])
            status = int(q.get('status', '2'))
            if status != m.status:
                text = STATUS_TEXT[status]
                if status == 1:
                    m.offline_since = None
                    self.event('module_online', q['link'], m.name, '',
                               'link %s: %s online' % (q['link'], m.name))
                else:
                    m.offline_since = m.offline_since or time.time()
                    self.event('module_offline', q['link'], m.name, '',
                               'link %s: %s offline: %s' % (q['link'], m.name, text))
                m.status = status
            return m.json(time.time())
        if action == 'port':
            link = self.find(q['link'])
            link['port_open'] = q.get('open', '1') == '1'
            if link['port_open']:
                link['reopens'] += 1
            self.event('port_up' if link['port_open'] else 'port_down', link['name'], '', '',
                       'link %s: %s %s' % (link['name'], link['device'],
                                           'open' if link['port_open'] else 'closed'))
            return {'name': link['name'], 'port_open': link['port_open']}
        if action == 'comm_loss':
            self.comm_loss = q.get('on', '1') == '1'
            self.event('comm_loss', '', '', '', 'modbus: comm loss: %s' % (
                'no request for 10 s, outputs to their safe state' if self.comm_loss
                else 'requests again'))
            return {'comm_loss': self.comm_loss}
        if action == 'outage':
            self.outage_until = time.time() + float(q.get('seconds', '5'))
            return {'outage_until': rfc3339(self.outage_until)}
        if action == 'user':
            self.user = ({'name': q['name'], 'operator': q.get('operator', '0') == '1'}
                         if q.get('name') else None)
            return {'user': self.user}
        if action == 'scada':
            self.scada = q.get('on', '1') == '1'
            return {'scada': self.scada}
        if action == 'hold':
            self.held = q.get('on', '1') == '1'
            self.answered.notify_all()
            return {'held': self.held}
        if action == 'answer':
            answer = {'result': q['result']}
            if 'error' in q:
                answer['error'] = q['error']
            self.answers.append((int(q['status']), answer))
            return {'answers': len(self.answers)}
        if action == 'writes':
            writes = list(self.writes)
            if q.get('clear') == '1':
                self.writes.clear()
            return writes
        raise KeyError('no control ' + action)

    def write(self, content_type, origin, body):
        """POST api/v1/write: recorded, then held while `held`, then answered (status, JSON)."""
        self.writes.append({'content_type': content_type, 'origin': origin,
                            'body': body.decode('utf-8', 'replace')})
        if not (self.user and self.user['operator']):
            return 403, {'result': 'forbidden', 'error': 'writes are for the users in '
                         'http.operators: sign in as one'}
        if content_type != 'application/json':
            return 415, {'result': 'unsupported_media_type',
                         'error': "a write's body is JSON: Content-Type: application/json"}
        self.answered.wait_for(lambda: not self.held, timeout=60)
        if self.answers:
            return self.answers.pop(0)
        try:
            w = json.loads(body)
            link, module, point, value = w['link'], w['module'], w['point'], w['value']
        except (ValueError, KeyError, TypeError) as e:
            return 400, {'result': 'bad_request', 'error': 'the body: %s' % e}
        value = str(value).lower() if isinstance(value, bool) else str(value)
        m = next((m for l in self.links if l['name'] == link for m in l['modules']
                  if m.id == module), None)
        if m is None:
            return 404, {'result': 'not_found', 'error': 'no module %s on link %s'
                         % (module, link)}
        refused = self.apply(m, point, value)
        if refused:
            return refused
        self.find(link)['writes']['confirmed'] += 1
        self.event('write', link, m.name, 'http %s@127.0.0.1' % self.user['name'],
                   'write by http %s@127.0.0.1 (%s): set %s/%s/%s = %s: confirmed'
                   % (self.user['name'], link, link, module, point, value))
        return 200, {'result': 'confirmed'}

    def apply(self, m, point, value):
        """A confirmed write's new value in the state; a refusal (status, answer) or None."""
        bit = re.fullmatch(r'out(\d+)', point)
        if m.type == 'dom16' and bit and int(bit.group(1)) < 16:
            if value not in SWITCH:
                return 400, {'result': 'invalid_value', 'error': 'send ON or OFF'}
            mask = 1 << int(bit.group(1))
            word = m.values['word'] or 0
            m.values['word'] = word | mask if SWITCH[value] else word & ~mask
        elif m.type == 'rgbdm' and point == 'colour':
            if value not in COLOURS and value not in [str(i) for i in range(8)]:
                return 400, {'result': 'invalid_value', 'error': 'send a colour'}
            m.values['colour'] = COLOURS.index(value) if value in COLOURS else int(value)
        elif m.type == 'mux8m' and point in ('pos', 'neg'):
            if value not in [str(i) for i in range(8)]:
                return 400, {'result': 'invalid_value', 'error': 'send 0-7'}
            m.values[point] = int(value)
        elif m.type == 'id2' and point == 'reset':
            if SWITCH.get(value) != 1:
                return 400, {'result': 'invalid_value', 'error': 'send ON'}
            m.values['reset_at'] = time.time()
        else:
            return 404, {'result': 'not_found', 'error': 'no writable point %s' % point}
        return None


class Handler(BaseHTTPRequestHandler):
    fixture = None  # set by serve()

    def log_message(self, fmt, *args):  # quiet: the self-test's output stays readable
        pass

    def send(self, code, ctype, body):
        data = body.encode() if isinstance(body, str) else body
        self.send_response(code)
        self.send_header('Content-Type', ctype)
        self.send_header('Content-Length', str(len(data)))
        self.send_header('Cache-Control', 'no-store')
        for name, value in SECURITY_HEADERS.items():
            self.send_header(name, value)
        self.end_headers()
        self.wfile.write(data)

    def route(self):
        url = urllib.parse.urlsplit(self.path)
        path = url.path
        if path == PREFIX:
            path = PREFIX + '/'
        if path.startswith(PREFIX + '/'):
            path = path[len(PREFIX):]
        return path, {k: v[-1] for k, v in urllib.parse.parse_qs(url.query).items()}

    def do_GET(self):
        path, _ = self.route()
        fx = self.fixture
        if path in ASSETS:
            name, ctype = ASSETS[path]
            # Read each time: edits show on reload.
            with open(os.path.join(PAGE_DIR, name), 'rb') as f:
                return self.send(200, ctype, f.read())
        if path in ('/api/v1/state', '/api/v1/trends'):
            with fx.lock:
                if time.time() < fx.outage_until:
                    self.close_connection = True  # no answer at all, as a dead daemon
                    return
                body = fx.state() if path.endswith('state') else fx.trends()
            return self.send(200, 'application/json', json.dumps(body))
        if path == '/healthz':
            with fx.lock:
                h = fx.state()['health']
            return self.send(200 if h['ok'] else 503, 'text/plain', 'ok\n' if h['ok']
                             else h['reason'] + '\n')
        if path == '/metrics':
            return self.send(200, 'text/plain; version=0.0.4',
                             '# fixture: the real daemon serves its metrics here\n')
        if path == '/map':
            return self.send(200, 'text/html; charset=utf-8',
                             '<!doctype html><title>map</title><p>fixture: the register map')
        self.send(404, 'text/plain', 'not found\n')

    def do_POST(self):
        path, q = self.route()
        if path == '/api/v1/write':
            body = self.rfile.read(int(self.headers.get('Content-Length') or 0))
            with self.fixture.lock:
                status, answer = self.fixture.write(self.headers.get('Content-Type'),
                                                    self.headers.get('Origin'), body)
            return self.send(status, 'application/json', json.dumps(answer))
        if not path.startswith('/control/'):
            return self.send(404, 'text/plain', 'not found\n')
        try:
            with self.fixture.lock:
                out = self.fixture.control(path[len('/control/'):], q)
        except (KeyError, ValueError) as e:
            return self.send(400, 'text/plain', 'bad control request: %s\n' % e)
        self.send(200, 'application/json', json.dumps(out))


def serve(host='127.0.0.1', port=0):
    """Starts the fixture in a background thread; returns the server (server_address has the
    port; call shutdown() to stop)."""
    handler = type('FixtureHandler', (Handler,), {'fixture': Fixture()})
    server = ThreadingHTTPServer((host, port), handler)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--host', default='127.0.0.1')
    ap.add_argument('--port', type=int, default=8080)
    args = ap.parse_args()
    server = serve(args.host, args.port)
    print('fixture: http://%s:%d/ (also under %s/)' % (*server.server_address[:2], PREFIX),
          flush=True)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        server.shutdown()


if __name__ == '__main__':
    main()
