'use strict';
// Co-simulation runner: the bridge firmware on an emulated ATmega328P at 16 MHz (avr8js,
// cycle-accurate), wired to a parent process over stdin/stdout. Its USART0 carries the host link;
// the servo pin (PB1, OC1A) is measured pulse by pulse; a model ESC answers on the telemetry pin
// (PD2) in HoTT or KISS frames, bit by bit. The physics lives in the parent, which answers the
// runner's ticks with the ESC frame to send next (thruster_fdd/core/bridge/firmware_cosim.py).
//
// Usage: node runner.js '<json options>'  (see OPTIONS below). Messages both ways are
// [u8 type][u32 payload length][payload], little-endian (the MSG_* and CMD_* constants).

const fs = require('fs');
const {
  CPU, avrInstruction, AVRClock, clockConfig, AVREEPROM, EEPROMMemoryBackend, AVRIOPort,
  portBConfig, portCConfig, portDConfig, AVRTimer, timer0Config, timer1Config, timer2Config,
  AVRUSART, usart0Config, AVRWatchdog, watchdogConfig,
} = require('avr8js');

const FREQ_HZ = 16e6;
const FLASH_WORDS = 16384;
const SRAM_BYTES = 2048;
const RAMEND = 0x8ff;
const EEPROM_BYTES = 1024;
const MCUSR = 0x54;
const PORF = 0x01;
const WDRF = 0x08;
const DDRD = 0x2a;
const SERVO_PIN = 1; // PB1
const ESC_PIN = 2; // PD2
const SMCR = 0x53;
const UCSRA_RXC = 0x80; // USART0: a received byte is unread
const UCSRB_RXEN = 0x10; // USART0: the receiver is on
const SLEEP = 0x9588;
const RJMP_SELF = 0xcfff; // rjmp .-2: a loop that never ends

// Runner -> parent.
const MSG_UART_TX = 0x01; // f64 t, bytes the AVR sent on USART0
const MSG_PULSES = 0x02; // (f64 t_rise, f32 width_us)*
const MSG_TICK = 0x03; // f64 t, f32 last pulse width (µs, NaN if none), f32 its age (s)
const MSG_RX_DONE = 0x04; // u32 chunk id, f64 t its last byte was received, u8 dropped
const MSG_ESC_SENT = 0x05; // u32 frame id, f64 t the ESC started sending it
const MSG_RESET = 0x06; // f64 t, u8 MCUSR cause bits
// MSG_STATS: f64 t, f64 wall s, f64 busy s, u32 loop max cycles, u32 loops, u32 slips,
// u32 deepest stack in bytes (0 unless trackStack)
const MSG_STATS = 0x07;
const MSG_POLL = 0x08; // f64 t, request bytes the ESC received
// Parent -> runner.
const CMD_UART_RX = 0x11; // u32 chunk id, f64 not before t (s), bytes for the AVR's USART0
const CMD_ESC_FRAME = 0x12; // u32 frame id, u8 once, bytes: the ESC's next reply
const CMD_ESC_MUTE = 0x13; // f64 seconds the ESC stays silent
const CMD_HANG = 0x14; // the main loop stops at its entry until the watchdog resets the AVR
const CMD_GO = 0x15; // start simulating
const CMD_STOP = 0x16; // send the last stats and exit

// OPTIONS (JSON in argv[2]):
//   hex: firmware Intel HEX file; esc: "hott" | "kiss"; loopAddress: byte address of the main
//   loop's step function (from the ELF); eeprom: byte array written at EEPROM address 0;
//   realtime: pace to the wall clock (else as fast as possible); durationS: stop after this much
//   virtual time (0: never); tickS: period of the physics ticks; hott: {firstByteUs, byteUs};
//   kissPeriodS: period of the KISS ESC's frames; trackStack: record the deepest stack (slower).
const opts = Object.assign(
  {
    esc: 'hott',
    eeprom: [],
    realtime: true,
    durationS: 0,
    tickS: 0.01,
    hott: { firstByteUs: 4000, byteUs: 1200 },
    kissPeriodS: 0.02,
    trackStack: false,
  },
  JSON.parse(process.argv[2]),
);

const SLICE_CYCLES = 0.005 * FREQ_HZ; // longest run between two looks at the outside world
const CHUNK_CYCLES = 0.001 * FREQ_HZ; // granularity of ticks and host-byte deliveries
const MAX_LAG_CYCLES = 0.2 * FREQ_HZ; // further behind the wall clock than this: skip ahead

function loadHex(path) {
  const flash = new Uint8Array(FLASH_WORDS * 2);
  for (const line of fs.readFileSync(path, 'utf8').split('\n')) {
    if (line[0] !== ':' || line.substr(7, 2) !== '00') continue;
    const count = parseInt(line.substr(1, 2), 16);
    const addr = parseInt(line.substr(3, 4), 16);
    for (let i = 0; i < count; i++) flash[addr + i] = parseInt(line.substr(9 + 2 * i, 2), 16);
  }
  return new Uint16Array(flash.buffer);
}

const program = loadHex(opts.hex);
const loopPc = opts.loopAddress / 2;
const eeprom = new EEPROMMemoryBackend(EEPROM_BYTES);
opts.eeprom.forEach((b, i) => { eeprom.memory[i] = b; });

// ---- output to the parent ------------------------------------------------------------------

let out = [];
function message(type, payload) {
  const head = Buffer.alloc(5);
  head.writeUInt8(type, 0);
  head.writeUInt32LE(payload.length, 1);
  out.push(head, payload);
}
function f64(v) { const b = Buffer.alloc(8); b.writeDoubleLE(v); return b; }
function u32(v) { const b = Buffer.alloc(4); b.writeUInt32LE(v >>> 0); return b; }

let txBytes = [];
let txStart = 0;
let txLast = 0;
let pulses = [];
function flushTx() {
  if (txBytes.length) {
    message(MSG_UART_TX, Buffer.concat([f64(txStart), Buffer.from(txBytes)]));
    txBytes = [];
  }
}
function flush() {
  // A burst still being sent stays for the next flush: a message is one whole burst.
  if (m && vnow() - txLast > 2 * m.usart.cyclesPerChar) flushTx();
  if (pulses.length) {
    const b = Buffer.alloc(12 * pulses.length);
    pulses.forEach(([t, w], i) => { b.writeDoubleLE(t, 12 * i); b.writeFloatLE(w, 12 * i + 8); });
    message(MSG_PULSES, b);
    pulses = [];
  }
  if (out.length) {
    process.stdout.write(Buffer.concat(out));
    out = [];
  }
}

// ---- the machine ---------------------------------------------------------------------------

let vbase = 0; // virtual cycles before the current machine's cycle 0
let m = null;
let resetCause = 0;
let hung = false;
function vnow() { return vbase + m.cpu.cycles; }
function seconds(cycles) { return cycles / FREQ_HZ; }

// avr8js clears a received byte's RXC flag on every UCSR0B write that leaves the receiver on.
// The hardware drops unread data only when the receiver is switched off (ATmega328P datasheet,
// UCSRnA: RXCn). The firmware writes UCSR0B whenever a telemetry burst starts or ends (UDRIE0),
// so a host byte that completed just then never raised its interrupt and the next overwrote
// it (4 and 8 of 2000 queries in a continuous stream went unanswered; test_firmware_cosim).
function keepUnreadByte(cpu, usart) {
  const { UCSRA, UCSRB } = usart0Config;
  const write = cpu.writeHooks[UCSRB];
  cpu.writeHooks[UCSRB] = (value, oldValue, ...rest) => {
    const unread = cpu.data[UCSRA] & UCSRA_RXC;
    const handled = write(value, oldValue, ...rest);
    if (!(value & UCSRB_RXEN)) cpu.clearInterrupt(usart.RXC);
    else if (unread) cpu.setInterruptFlag(usart.RXC);
    return handled;
  };
}

// A reset in avr8js only rewinds the PC; the real chip also resets every peripheral, so a new
// machine is built instead (flash, EEPROM and the outside world are kept).
function createMachine(cause) {
  const cpu = new CPU(new Uint16Array(program), SRAM_BYTES);
  const resetPc = cpu.reset.bind(cpu);
  cpu.reset = () => { resetPc(); resetCause = WDRF; };
  const clock = new AVRClock(cpu, FREQ_HZ, clockConfig);
  const timerConfigs = [timer0Config, timer1Config, timer2Config];
  const machine = {
    cpu,
    portB: new AVRIOPort(cpu, portBConfig),
    portC: new AVRIOPort(cpu, portCConfig),
    portD: new AVRIOPort(cpu, portDConfig),
    timers: timerConfigs.map((c) => new AVRTimer(cpu, c)),
    usart: new AVRUSART(cpu, usart0Config, FREQ_HZ),
    eeprom: new AVREEPROM(cpu, eeprom),
    watchdog: new AVRWatchdog(cpu, watchdogConfig, clock),
  };
  cpu.data[MCUSR] = cause;
  countTimersLazily(cpu, machine.timers, timerConfigs);
  machine.usart.onByteTransmit = (b) => {
    // One message per burst, stamped with its first byte: frames are sent back to back.
    const now = vnow();
    if (txBytes.length && now - txLast > 2 * machine.usart.cyclesPerChar) flushTx();
    if (!txBytes.length) txStart = seconds(now);
    txLast = now;
    txBytes.push(b);
  };
  machine.usart.onRxComplete = onHostByteReceived;
  keepUnreadByte(cpu, machine.usart);
  machine.portB.addListener(onServoPin);
  machine.portD.addListener((value) => esc.onAvrPin(value));
  machine.portD.setPin(ESC_PIN, true); // pull-up: the idle wire is high
  return machine;
}

// avr8js advances a timer with a clock event at every prescaled tick (2 million a second for
// Timer1 at clk/8). Its count function accepts any number of elapsed ticks, so the event is
// scheduled instead at the next tick where something can be seen: a compare match or the
// wrap at TOP (flags, interrupts, output pins). Reads of TCNT count up to the present as before;
// writes that move those ticks (OCRx, ICR, TCCRxA) recount and reschedule at once. Modes other
// than normal, CTC and fast PWM keep the event per tick.
const LAZY_MODES = new Set([0, 2, 3]); // avr8js TimerMode: Normal, CTC, FastPWM
function ticksToEvent(timer) {
  const t = timer.tcnt;
  const top = timer.TOP;
  if (!LAZY_MODES.has(timer.timerMode) || timer.tcntUpdated || t > top) return 1;
  let ticks = top - t + 1;
  for (const ocr of [timer.ocrA, timer.ocrB, timer.ocrC]) {
    if (ocr > t && ocr - t < ticks) ticks = ocr - t;
  }
  return ticks;
}
function countTimersLazily(cpu, timers, configs) {
  const byCount = new Map(timers.map((timer) => [timer.count, timer]));
  const addClockEvent = cpu.addClockEvent.bind(cpu);
  cpu.addClockEvent = (callback, cycles) => {
    const timer = byCount.get(callback);
    // A positive delay is count()'s "next tick"; 0 is a request to count now.
    if (timer && cycles > 0) cycles += (ticksToEvent(timer) - 1) * timer.divider;
    return addClockEvent(callback, cycles);
  };
  timers.forEach((timer, i) => {
    const c = configs[i];
    for (const addr of [c.OCRA, c.OCRB, c.OCRC, c.ICR, c.TCCRA].filter(Boolean)) {
      const hook = cpu.writeHooks[addr];
      cpu.writeHooks[addr] = (...args) => {
        const handled = hook(...args);
        cpu.updateClockEvent(timer.count, 0);
        return handled;
      };
    }
  });
}

function rebuild() {
  vbase += m.cpu.cycles;
  const cause = resetCause;
  resetCause = 0;
  hung = false;
  asleep = false;
  m = createMachine(cause);
  passStart = -1;
  inflight = null;
  esc.onReset();
  message(MSG_RESET, Buffer.concat([f64(seconds(vnow())), Buffer.from([cause])]));
}

// ---- servo pulses --------------------------------------------------------------------------

let riseV = -1;
let lastWidth = NaN;
let lastFallV = -1;
function onServoPin(value) {
  const high = (value >> SERVO_PIN) & 1;
  if (high && riseV < 0) {
    riseV = vnow();
  } else if (!high && riseV >= 0) {
    lastFallV = vnow();
    lastWidth = (lastFallV - riseV) / (FREQ_HZ / 1e6);
    pulses.push([seconds(riseV), lastWidth]);
    riseV = -1;
  }
}

// ---- host bytes into USART0 ----------------------------------------------------------------

const hostQueue = []; // {id, notBefore (cycles), bytes, next}
let inflight = null; // the chunk whose byte is on the wire
function feedHost() {
  const { usart } = m;
  while (hostQueue.length && !inflight) {
    const chunk = hostQueue[0];
    if (chunk.notBefore > vnow() || usart.rxBusy) return;
    if (!usart.rxEnable) {
      // No receiver yet (the AVR is booting): the bytes are lost, as on the wire.
      hostQueue.shift();
      message(MSG_RX_DONE, Buffer.concat([u32(chunk.id), f64(seconds(vnow())), Buffer.from([1])]));
      continue;
    }
    usart.writeByte(chunk.bytes[chunk.next++]);
    inflight = chunk;
  }
}
function onHostByteReceived() {
  const chunk = inflight;
  inflight = null;
  if (chunk && chunk.next >= chunk.bytes.length) {
    hostQueue.shift();
    message(MSG_RX_DONE, Buffer.concat([u32(chunk.id), f64(seconds(vnow())), Buffer.from([0])]));
  }
  feedHost();
}

// ---- the model ESC -------------------------------------------------------------------------

// Sends `bytes` on PD2 as 8N1 frames starting at virtual cycle `start`, byte k at
// start + k * byteCycles, one event per bit so the AVR sees each edge at its cycle.
function sendSerial(bytes, start, bitCycles, byteCycles, onDone) {
  const edges = [];
  bytes.forEach((byte, k) => {
    const t0 = start + k * byteCycles;
    const levels = [0, ...Array.from({ length: 8 }, (_, i) => (byte >> i) & 1), 1];
    levels.forEach((level, i) => edges.push([Math.round(t0 + i * bitCycles), level]));
  });
  const machine = m;
  let i = 0;
  const fire = () => {
    if (m !== machine) return; // the AVR was reset meanwhile
    machine.portD.setPin(ESC_PIN, !!edges[i][1]);
    i += 1;
    if (i < edges.length) machine.cpu.addClockEvent(fire, edges[i][0] - vnow());
    else onDone();
  };
  machine.cpu.addClockEvent(fire, Math.max(1, edges[0][0] - vnow()));
}

class Esc {
  constructor(kind) {
    this.kind = kind;
    this.frame = null; // {id, bytes}
    this.once = null;
    this.muteUntil = 0;
    this.sending = false;
    this.receiving = false;
    this.request = [];
    this.nextKiss = 0;
  }

  setFrame(id, once, bytes) {
    if (once) this.once = { id, bytes };
    else this.frame = { id, bytes };
  }

  onReset() {
    this.sending = false;
    this.receiving = false;
    this.request = [];
  }

  wire() {
    const drivenByAvr = m.cpu.data[DDRD] & (1 << ESC_PIN);
    return drivenByAvr ? (m.portD.lastValue >> ESC_PIN) & 1 : (m.cpu.data[0x29] >> ESC_PIN) & 1;
  }

  // HoTT: decode what the AVR sends (the poll) at 19200 baud, sampling mid-bit.
  onAvrPin(value) {
    if (this.kind !== 'hott' || this.receiving || this.sending) return;
    if (!(m.cpu.data[DDRD] & (1 << ESC_PIN)) || (value >> ESC_PIN) & 1) return;
    this.receiving = true;
    const bit = FREQ_HZ / 19200;
    const start = vnow();
    const machine = m;
    let byte = 0;
    let k = 0;
    const sample = () => {
      if (m !== machine) return;
      const level = this.wire();
      if (k < 8) {
        byte |= level << k;
        k += 1;
        machine.cpu.addClockEvent(sample, Math.round(start + (1.5 + k) * bit) - vnow());
        return;
      }
      this.receiving = false;
      if (level) this.onRequestByte(byte);
    };
    machine.cpu.addClockEvent(sample, Math.round(start + 1.5 * bit) - vnow());
  }

  onRequestByte(byte) {
    const now = vnow();
    this.request = this.request.filter(([, t]) => now - t < 0.003 * FREQ_HZ);
    this.request.push([byte, now]);
    const bytes = this.request.map(([b]) => b);
    if (bytes.length < 2) return;
    message(MSG_POLL, Buffer.concat([f64(seconds(now)), Buffer.from(bytes.slice(-2))]));
    const polled = bytes[bytes.length - 2] === 0x80 && bytes[bytes.length - 1] === 0x8c;
    this.request = [];
    if (polled) this.reply(now + (opts.hott.firstByteUs * FREQ_HZ) / 1e6,
      FREQ_HZ / 19200, (opts.hott.byteUs * FREQ_HZ) / 1e6);
  }

  reply(start, bitCycles, byteCycles) {
    const frame = this.once || this.frame;
    if (!frame || this.sending || vnow() < this.muteUntil) return;
    this.once = null;
    this.sending = true;
    message(MSG_ESC_SENT, Buffer.concat([u32(frame.id), f64(seconds(start))]));
    sendSerial(frame.bytes, start, bitCycles, byteCycles, () => { this.sending = false; });
  }

  // KISS: the ESC sends on its own every kissPeriodS, bytes back to back at 115200 baud.
  periodic(now) {
    if (this.kind !== 'kiss' || now < this.nextKiss) return;
    this.nextKiss = now + opts.kissPeriodS * FREQ_HZ;
    const bit = FREQ_HZ / 115200;
    this.reply(now + 1, bit, 10 * bit);
  }
}

const esc = new Esc(opts.esc);

// ---- main loop timing ----------------------------------------------------------------------

// A pass runs from the loop function's entry to the next SLEEP (or the next entry when the loop
// goes round without sleeping), interrupts included.
let passStart = -1;
let loopMax = 0;
let loops = 0;
let minSp = RAMEND;
function endPass(cycles) {
  if (passStart >= 0) loopMax = Math.max(loopMax, cycles - passStart);
  passStart = -1;
}
function onLoopEntry(cycles) {
  endPass(cycles);
  passStart = cycles;
  loops += 1;
}

// ---- running -------------------------------------------------------------------------------

let nextTick = 0;
function periodic() {
  const now = vnow();
  feedHost();
  esc.periodic(now);
  if (now >= nextTick) {
    nextTick = now + opts.tickS * FREQ_HZ;
    const age = lastFallV < 0 ? NaN : seconds(now - lastFallV);
    const b = Buffer.alloc(16);
    b.writeDoubleLE(seconds(now), 0);
    b.writeFloatLE(lastWidth, 8);
    b.writeFloatLE(age, 12);
    message(MSG_TICK, b);
  }
}

// avr8js executes SLEEP as a no-op; a sleeping AVR is halted until an interrupt is taken, so the
// runner jumps from one clock event (timer tick, serial byte, ESC bit) to the next instead.
let asleep = false;
function runUntil(end) {
  while (vnow() < end) {
    const { cpu } = m;
    const limit = Math.min(end, vnow() + CHUNK_CYCLES) - vbase;
    while (cpu.cycles < limit && !resetCause) {
      if (asleep) {
        const pc = cpu.pc;
        const next = cpu.nextClockEvent;
        cpu.cycles = next && next.cycles < limit ? Math.max(next.cycles, cpu.cycles) : limit;
        cpu.tick();
        asleep = cpu.pc === pc;
        continue;
      }
      const sleeping = cpu.progMem[cpu.pc] === SLEEP && cpu.data[SMCR] & 1;
      avrInstruction(cpu);
      if (opts.trackStack && cpu.SP < minSp) minSp = cpu.SP;
      const pc = cpu.pc;
      cpu.tick();
      if (sleeping) {
        endPass(cpu.cycles);
        asleep = cpu.pc === pc;
      } else if (cpu.pc === loopPc && !hung) {
        onLoopEntry(cpu.cycles);
      }
    }
    if (resetCause) rebuild();
    periodic();
  }
}

let wall0 = 0;
let v0 = 0;
let busyMs = 0;
let slips = 0;
let lagging = false;
let lastStats = 0;
let stopping = false;
function stats() {
  const b = Buffer.alloc(40);
  b.writeDoubleLE(seconds(vnow()), 0);
  b.writeDoubleLE((performance.now() - wall0) / 1000, 8);
  b.writeDoubleLE(busyMs / 1000, 16);
  b.writeUInt32LE(loopMax, 24);
  b.writeUInt32LE(loops >>> 0, 28);
  b.writeUInt32LE(slips, 32);
  b.writeUInt32LE(opts.trackStack ? RAMEND - minSp : 0, 36);
  message(MSG_STATS, b);
}

function finish() {
  stats();
  flushTx();
  flush();
  process.stdout.end(() => process.exit(0));
}

function slice() {
  if (stopping) return;
  const t = performance.now();
  let end = vnow() + SLICE_CYCLES;
  let behind = false;
  if (opts.realtime) {
    let target = v0 + ((t - wall0) * FREQ_HZ) / 1000;
    if (target - vnow() > MAX_LAG_CYCLES) {
      // The host cannot keep up: the backlog beyond 0.2 s is given up (virtual time falls
      // behind the wall clock) rather than run in one burst. One slip per such episode.
      if (!lagging) slips += 1;
      lagging = true;
      v0 -= target - vnow() - MAX_LAG_CYCLES;
      target = vnow() + MAX_LAG_CYCLES;
    } else if (target - vnow() < SLICE_CYCLES) {
      lagging = false;
    }
    behind = target > end;
    end = Math.min(end, target);
  }
  if (opts.durationS > 0) end = Math.min(end, opts.durationS * FREQ_HZ);
  runUntil(end);
  busyMs += performance.now() - t;
  if (t - lastStats > 1000) {
    lastStats = t;
    stats();
  }
  flush();
  if (opts.durationS > 0 && vnow() >= opts.durationS * FREQ_HZ) {
    stopping = true;
    finish();
    return;
  }
  if (!opts.realtime || behind) setImmediate(slice);
  else setTimeout(slice, 1);
}

// ---- input from the parent -----------------------------------------------------------------

let inbox = Buffer.alloc(0);
function onCommand(type, p) {
  if (type === CMD_UART_RX) {
    const notBefore = p.readDoubleLE(4) * FREQ_HZ;
    hostQueue.push({ id: p.readUInt32LE(0), notBefore, bytes: p.subarray(12), next: 0 });
  } else if (type === CMD_ESC_FRAME) {
    esc.setFrame(p.readUInt32LE(0), p.readUInt8(4), Buffer.from(p.subarray(5)));
  } else if (type === CMD_ESC_MUTE) {
    esc.muteUntil = vnow() + p.readDoubleLE(0) * FREQ_HZ;
  } else if (type === CMD_HANG) {
    hung = true;
    m.cpu.progMem[loopPc] = RJMP_SELF;
  } else if (type === CMD_GO) {
    wall0 = performance.now();
    v0 = vnow();
    lastStats = wall0;
    slice();
  } else if (type === CMD_STOP && !stopping) {
    stopping = true;
    finish();
  }
}
process.stdin.on('data', (data) => {
  inbox = Buffer.concat([inbox, data]);
  while (inbox.length >= 5) {
    const len = inbox.readUInt32LE(1);
    if (inbox.length < 5 + len) break;
    onCommand(inbox.readUInt8(0), inbox.subarray(5, 5 + len));
    inbox = inbox.subarray(5 + len);
  }
});
process.stdin.on('end', () => process.exit(0));

m = createMachine(PORF);
