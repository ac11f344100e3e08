// VDA 5050 2.0.0 vehicles nobody here wrote: vda-5050-lib's AgvController driving its
// VirtualAgvAdapter, one per vehicle, on the broker the tests name.
//
//   node agvs.mjs '{"brokerUrl": "mqtt://127.0.0.1:PORT", "speed": 0.5,
//                   "agvs": [{"manufacturer": "m", "serialNumber": "s", "x": 0, "y": 0,
//                             "mapId": "hall", "lastNodeId": "sq-0-0",
//                             "adapterOptions": {"initialBatteryCharge": 30}}]}'
//
// `adapterOptions` (optional) go to its VirtualAgvAdapter as they are: its battery's
// `initialBatteryCharge` (%), `batteryMaxReach` (metres on a full charge) and
// `fullBatteryChargeTime` (hours from 0 to 100 %), say.
//
// Prints "ready <serial>" for each vehicle once it is on line; SIGTERM stops them cleanly
// (OFFLINE), SIGKILL leaves their last wills (CONNECTIONBROKEN) to the broker.
import vda from "vda-5050-lib";

const { AgvController, VirtualAgvAdapter } = vda;
const spec = JSON.parse(process.argv[2]);
const controllers = [];

for (const agv of spec.agvs) {
  const controller = new AgvController(
    { manufacturer: agv.manufacturer, serialNumber: agv.serialNumber },
    { interfaceName: "uagv", transport: { brokerUrl: spec.brokerUrl }, vdaVersion: "2.0.0" },
    { agvAdapterType: VirtualAgvAdapter, publishStateInterval: spec.stateIntervalMs ?? 30000 },
    {
      initialPosition: { mapId: agv.mapId, x: agv.x, y: agv.y, theta: 0, lastNodeId: agv.lastNodeId },
      vehicleSpeed: spec.speed ?? 0.5,
      ...(agv.adapterOptions ?? {}),
    },
  );
  await controller.start();
  controllers.push(controller);
  console.log(`ready ${agv.serialNumber}`);
}

async function stop() {
  for (const controller of controllers) await controller.stop();
  process.exit(0);
}
process.on("SIGTERM", stop);
process.on("SIGINT", stop);
