// One aedes instance of a cluster on Redis, configured for gridfleet: the broker is aedes, its
// retained messages, sessions, QoS 1 queues and wills in Redis (aedes-persistence-redis), its
// messages between instances over Redis (mqemitter-redis). This file only configures it: where
// Redis is, where to listen, the instance's id and heartbeat, and the accounts file
// 'gridfleet accounts aedes' writes (none: anonymous, anyone may do anything).
//
//   node broker/aedes/launcher.mjs --redis redis://127.0.0.1:6379 --port 1883 --ws-port 9001 \
//     [--host 127.0.0.1] [--id aedes-0] [--heartbeat-interval 60000] [--accounts aedes-accounts.json]

import { pbkdf2, timingSafeEqual } from 'node:crypto'
import { readFileSync } from 'node:fs'
import { createServer as createHttpServer } from 'node:http'
import { createServer as createTcpServer } from 'node:net'
import { parseArgs } from 'node:util'

import { Aedes } from 'aedes'
import persistenceRedis from 'aedes-persistence-redis'
import mqemitterRedis from 'mqemitter-redis'
import { WebSocketServer, createWebSocketStream } from 'ws'

const { values: opts } = parseArgs({
  options: {
    redis: { type: 'string', default: 'redis://127.0.0.1:6379' },
    host: { type: 'string', default: '127.0.0.1' },
    port: { type: 'string', default: '1883' },
    'ws-port': { type: 'string' },
    id: { type: 'string' },
    'heartbeat-interval': { type: 'string', default: '60000' },
    accounts: { type: 'string' }
  }
})

const say = (line) => process.stderr.write(`aedes ${opts.id ?? ''}: ${line}\n`.replace(' :', ':'))

/** ioredis options from a redis:// URL (host, port, database, password). */
function redisOptions (url) {
  const parsed = new URL(url)
  return {
    host: parsed.hostname || '127.0.0.1',
    port: Number(parsed.port || 6379),
    db: Number(parsed.pathname.slice(1) || 0),
    ...(parsed.password ? { password: decodeURIComponent(parsed.password) } : {})
  }
}

/** Whether MQTT topic filter `filter` matches `topic` (a name, or a filter read as a name). */
function matches (filter, topic) {
  const want = filter.split('/')
  const got = topic.split('/')
  if (got[0].startsWith('$') && !want[0].startsWith('$') && (want[0] === '+' || want[0] === '#')) {
    return false // MQTT-4.7.2-1: wildcards at the first level never match $ topics
  }
  for (let i = 0; i < want.length; i++) {
    if (want[i] === '#') return true
    if (i >= got.length) return false
    if (want[i] !== '+' && want[i] !== got[i]) return false
  }
  return want.length === got.length
}

/** Whether every topic subscription filter `sub` can match is one `allowed` matches. */
function covers (allowed, sub) {
  const want = allowed.split('/')
  const got = sub.split('/')
  for (let i = 0; i < want.length; i++) {
    if (want[i] === '#') return true
    if (i >= got.length || got[i] === '#') return false
    if (want[i] === '+') continue
    if (got[i] === '+' || got[i] !== want[i]) return false
  }
  return want.length === got.length
}

const DENIED = Symbol('denied by the accounts file')

/** The hooks that enforce the accounts file's users and their publish and subscribe filters. */
function accountHooks (users) {
  const verify = (hash, password) => new Promise((resolve) => {
    if (hash.algorithm !== 'pbkdf2-sha512') return resolve(false)
    const digest = Buffer.from(hash.digest, 'base64')
    pbkdf2(password, Buffer.from(hash.salt, 'base64'), hash.iterations, digest.length, 'sha512',
      (err, derived) => resolve(!err && timingSafeEqual(derived, digest)))
  })
  const userOf = (client) => (client ? users[client.gridfleetUser] : undefined)
  return {
    authenticate (client, username, password, callback) {
      const user = username === undefined ? undefined : users[username]
      if (user === undefined || password === undefined) {
        return callback(Object.assign(new Error('Not authorized'), { returnCode: 5 }), false)
      }
      verify(user.hash, password).then((ok) => {
        if (!ok) return callback(Object.assign(new Error('Not authorized'), { returnCode: 5 }), false)
        client.gridfleetUser = username
        // A will the account may not publish is dropped here, before it is stored in Redis: a
        // survivor publishing the wills of a dead instance knows no account (its client is null).
        const will = client._will
        if (will && !user.publish.some((f) => matches(f, will.topic))) client._will = null
        callback(null, true)
      })
    },
    // Refused publishes are dropped, acknowledged (MQTT-3.3.5-2 allows it), as Mosquitto does:
    // aedes itself closes the connection of a client whose publish is refused.
    authorizePublish (client, packet, callback) {
      if (packet.topic.startsWith('$SYS')) {
        packet[DENIED] = true
      } else if (client !== null && packet.brokerId === undefined) {
        const user = userOf(client)
        if (user === undefined || !user.publish.some((f) => matches(f, packet.topic))) {
          packet[DENIED] = true
        }
      } // else a stored will, checked at its CONNECT (above)
      callback(null)
    },
    authorizeSubscribe (client, sub, callback) {
      const user = userOf(client)
      const ok = user !== undefined && user.subscribe.some((f) => covers(f, sub.topic))
      callback(null, ok ? sub : null) // null: granted 0x80, refused
    },
    authorizeForward (client, packet) {
      const user = userOf(client)
      if (user === undefined || !user.subscribe.some((f) => matches(f, packet.topic))) return null
      return packet
    }
  }
}

let hooks = {}
if (opts.accounts !== undefined) {
  const { users } = JSON.parse(readFileSync(opts.accounts, 'utf8'))
  hooks = accountHooks(users)
}

const broker = await Aedes.createBroker({
  id: opts.id,
  heartbeatInterval: Number(opts['heartbeat-interval']),
  persistence: persistenceRedis(redisOptions(opts.redis)),
  // No ready check on the emitter's connections: ioredis 5.8.2 and later may run its INFO on the
  // subscriber connection once it is subscribed, and the instance died of it seconds after a
  // restart ("Connection in subscriber mode, only subscriber commands may be used"; ioredis
  // #2037, #2099).
  mq: mqemitterRedis({ ...redisOptions(opts.redis), enableReadyCheck: false }),
  ...hooks
})
// One publish at a time, in the order they come, each once aedes is done with it (stored,
// emitted to Redis). aedes numbers each message as it starts and a subscriber drops one numbered
// below the last it had from this instance (its dedupe); a retained message, stored in Redis
// first, was overtaken by a plain one published after it, and lost: 2 to 6 runs in 20 of a
// retained, a plain and a retained message published back to back (aedes #994, #955).
// A publish the accounts refused is acknowledged and dropped here (authorizePublish).
const publishNow = broker.publish.bind(broker)
let previous = Promise.resolve()
broker.publish = (packet, client, done) => {
  if (typeof client === 'function') [client, done] = [null, client]
  if (packet[DENIED]) return done && process.nextTick(done, null)
  previous = previous.then(() => new Promise((resolve) => {
    publishNow(packet, client, (err) => {
      resolve()
      if (done) done(err)
    })
  }))
}

const listening = (server, port) => new Promise((resolve, reject) => {
  server.once('error', reject)
  server.listen(Number(port), opts.host, resolve)
})
const tcp = createTcpServer(broker.handle)
await listening(tcp, opts.port)
let ws
if (opts['ws-port'] !== undefined) {
  ws = createHttpServer()
  const wss = new WebSocketServer({ server: ws })
  wss.on('connection', (socket, req) => broker.handle(createWebSocketStream(socket), req))
  await listening(ws, opts['ws-port'])
}
say(`started as ${broker.id}: mqtt://${opts.host}:${opts.port}` +
  (ws ? `, ws://${opts.host}:${opts['ws-port']}` : '') +
  `, Redis ${opts.redis}, heartbeat ${opts['heartbeat-interval']} ms, ` +
  (opts.accounts === undefined ? 'anonymous' : `accounts ${opts.accounts}`))

function stop (signal) {
  tcp.close()
  ws?.close()
  broker.close(() => {
    say(`stopped (${signal})`)
    process.exit(0)
  })
}
process.once('SIGTERM', () => stop('SIGTERM'))
process.once('SIGINT', () => stop('SIGINT'))
