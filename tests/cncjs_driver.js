// Drives CNCjs (tests/peers/npm/cncjs) through its socket.io API, as its web UI does: the test writes
// requests as JSON lines on stdin ({"emit": [event, ...args]}; a callback's answer comes back as
// {"ev": "callback", "id": n, "data": [...]}), and every event CNCjs sends is printed as a JSON line
// ({"ev": name, "data": [...]}). Usage: node cncjs_driver.js URL SECRET
'use strict';
const path = require('path');
const readline = require('readline');
const base = path.join(__dirname, 'peers', 'npm', 'cncjs', 'node_modules');
const io = require(path.join(base, 'socket.io-client'));
const jwt = require(path.join(base, 'jsonwebtoken'));

const [url, secret] = process.argv.slice(2);
const token = jwt.sign({ id: '', name: 'pmctl-test' }, secret, { expiresIn: '1h' });   // as the UI's session
const say = (ev, data) => process.stdout.write(JSON.stringify({ ev, data }) + '\n');
const socket = io.connect(url, { query: 'token=' + token, transports: ['websocket'] });
['connect', 'disconnect', 'error', 'connect_error', 'startup', 'serialport:open', 'serialport:close',
  'serialport:error', 'serialport:read', 'serialport:write', 'controller:state', 'controller:settings',
  'sender:status', 'workflow:state', 'feeder:status', 'gcode:load'].forEach((ev) => {
  socket.on(ev, (...args) => say(ev, ev === 'gcode:load' ? [args[0]] : args));
});
let n = 0;
readline.createInterface({ input: process.stdin }).on('line', (line) => {
  const req = JSON.parse(line);
  const id = ++n;
  socket.emit(...req.emit, (...answer) => say('callback', { id, answer }));
  say('sent', { id, emit: req.emit[0] });
});
