//! gonio firmware for the STM32F411CEU6 "Black Pill": board glue only.
//!
//! Clocks, pins in their idle state, USB CDC-ACM and defmt logging. Every decision is made
//! by the `firmware` library ([`firmware::Device`]): this crate moves bytes between the
//! USB serial port and the device and logs what happened.
//!
//! Tasks:
//! - `usb_task`: runs the USB device stack (enumeration, control requests).
//! - `link_task`: CDC-ACM bytes in → `Device::receive` → reply frames out.
#![no_std]
#![no_main]

mod pins;

use defmt::{error, info, warn};
use embassy_executor::Spawner;
use embassy_stm32::time::Hertz;
use embassy_stm32::usb::{self, Driver};
use embassy_stm32::{Config, bind_interrupts, peripherals};
use embassy_time::Instant;
use embassy_usb::class::cdc_acm::{CdcAcmClass, State};
use embassy_usb::driver::EndpointError;
use embassy_usb::{Builder, UsbDevice};
use firmware::Device;
use firmware::config::InstrumentConfig;
use heapless::Vec;
use protocol::{MAX_FRAME_LEN, PROTOCOL_VERSION, USB_PID, USB_PRODUCT, USB_VID};
use static_cell::StaticCell;
use {defmt_rtt as _, panic_probe as _};

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<peripherals::USB_OTG_FS>;
});

type UsbDriver = Driver<'static, peripherals::USB_OTG_FS>;

/// Full-speed bulk packet size of the CDC data endpoints.
const USB_PACKET: u16 = 64;

/// HSE 25 MHz → PLL (VCO 192 MHz) → SYSCLK 96 MHz, USB 48 MHz.
fn clock_config() -> Config {
    use embassy_stm32::rcc::{
        AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllMul, PllPDiv, PllPreDiv, PllQDiv, PllSource, Sysclk,
    };
    let mut config = Config::default();
    config.rcc.hse = Some(Hse { freq: Hertz(25_000_000), mode: HseMode::Oscillator });
    config.rcc.pll_src = PllSource::HSE;
    config.rcc.pll = Some(Pll {
        prediv: PllPreDiv::DIV25,     // 1 MHz VCO input
        mul: PllMul::MUL192,          // 192 MHz VCO
        divp: Some(PllPDiv::DIV2),    // 96 MHz SYSCLK
        divq: Some(PllQDiv::DIV4),    // 48 MHz USB
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV1; // 96 MHz
    config.rcc.apb1_pre = APBPrescaler::DIV2; // 48 MHz (APB1 max 50 MHz)
    config.rcc.apb2_pre = APBPrescaler::DIV1; // 96 MHz
    config
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clock_config());
    info!("gonio board: firmware {}, protocol v{}", firmware::FIRMWARE_VERSION, PROTOCOL_VERSION);

    let pins = pins::take_board_pins!(p).into_idle();

    static EP_OUT_BUFFER: StaticCell<[u8; 256]> = StaticCell::new();
    let mut usb_config = usb::Config::default();
    // Bus-powered board: no VBUS sensing (PA9 stays free for the driver UART).
    usb_config.vbus_detection = false;
    let driver = Driver::new_fs(p.USB_OTG_FS, Irqs, p.PA12, p.PA11, EP_OUT_BUFFER.init([0; 256]), usb_config);

    let mut config = embassy_usb::Config::new(USB_VID, USB_PID);
    config.manufacturer = Some("gonio");
    config.product = Some(USB_PRODUCT);
    // The chip's unique id, so several instruments on one host can be told apart.
    config.serial_number = Some(embassy_stm32::uid::uid_hex());
    config.max_power = 100;
    config.max_packet_size_0 = 64;

    static CONFIG_DESCRIPTOR: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS_DESCRIPTOR: StaticCell<[u8; 256]> = StaticCell::new();
    static CONTROL_BUF: StaticCell<[u8; 64]> = StaticCell::new();
    static CDC_STATE: StaticCell<State> = StaticCell::new();
    let mut builder = Builder::new(
        driver,
        config,
        CONFIG_DESCRIPTOR.init([0; 256]),
        BOS_DESCRIPTOR.init([0; 256]),
        &mut [], // no MS OS descriptors
        CONTROL_BUF.init([0; 64]),
    );
    let class = CdcAcmClass::new(&mut builder, CDC_STATE.init(State::new()), USB_PACKET);
    let usb = builder.build();

    spawner.must_spawn(usb_task(usb));
    spawner.must_spawn(link_task(class, pins.led));

    // Keep the instrument pins at their idle levels for good (the motion and detector
    // layers will take them over).
    let _hold = pins.hold;
    let _detector = pins.detector;
    core::future::pending::<()>().await;
}

#[embassy_executor::task]
async fn usb_task(mut usb: UsbDevice<'static, UsbDriver>) -> ! {
    usb.run().await
}

#[embassy_executor::task]
async fn link_task(mut class: CdcAcmClass<'static, UsbDriver>, mut led: embassy_stm32::gpio::Output<'static>) -> ! {
    let mut device = Device::new(InstrumentConfig::REFERENCE);
    loop {
        class.wait_connection().await;
        info!("USB configured: serving the host");
        let _ = serve(&mut class, &mut device, &mut led).await;
        device.disconnected();
        led.set_high();
        info!("USB disconnected: waiting for a host");
    }
}

/// Move bytes between the CDC-ACM port and the device until the USB link goes away.
async fn serve(
    class: &mut CdcAcmClass<'static, UsbDriver>,
    device: &mut Device,
    led: &mut embassy_stm32::gpio::Output<'static>,
) -> Result<(), EndpointError> {
    let mut rx = [0u8; USB_PACKET as usize];
    // The device answers at most one frame per received byte; two frames of room.
    let mut tx: Vec<u8, { 2 * MAX_FRAME_LEN }> = Vec::new();
    loop {
        let n = class.read_packet(&mut rx).await?;
        for byte in &rx[..n] {
            let mut overflow = false;
            let was_connected = device.handshake_done();
            device.receive(core::slice::from_ref(byte), now_us(), &mut |frame: &[u8]| {
                overflow |= tx.extend_from_slice(frame).is_err();
            });
            if overflow {
                error!("reply frames overflowed the {}-byte USB buffer; dropped", tx.capacity());
            }
            if let Some(version) = device.take_refused_version() {
                warn!("handshake refused: version mismatch (host protocol v{}, firmware protocol v{})", version, PROTOCOL_VERSION);
            }
            match (was_connected, device.handshake_done()) {
                (false, true) => info!("handshake done: host speaks protocol v{}", PROTOCOL_VERSION),
                (true, false) => info!("handshake lost"),
                _ => {}
            }
            led.set_level(if device.handshake_done() { embassy_stm32::gpio::Level::Low } else { embassy_stm32::gpio::Level::High });
            if !tx.is_empty() {
                write_transfer(class, &tx).await?;
                tx.clear();
            }
        }
    }
}

/// Send `bytes` as one USB IN transfer: 64-byte packets, closed by a zero-length packet
/// when the last one is full (otherwise the host keeps waiting for more of the transfer).
async fn write_transfer(class: &mut CdcAcmClass<'static, UsbDriver>, bytes: &[u8]) -> Result<(), EndpointError> {
    let packet = class.max_packet_size() as usize;
    for chunk in bytes.chunks(packet) {
        class.write_packet(chunk).await?;
    }
    if bytes.len() % packet == 0 {
        class.write_packet(&[]).await?;
    }
    Ok(())
}

fn now_us() -> u64 {
    Instant::now().as_micros()
}
