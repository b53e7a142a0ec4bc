// The HardFault entry of the gonio firmware (the board, src/fault.rs, and the on-target
// tests, firmware/target-tests): nothing here uses the stack, which may be past its end.
// r0 = the stack pointer of the context that faulted (MSP or PSP, by EXC_RETURN bit 2);
// then MSP = _stack_start (the top of the stack region, given up: we never return), and
// on to the handler, `extern "C" fn(sp: u32) -> !`.
    .section .HardFault.gonio, "ax"
    .global HardFault
    .type HardFault, %function
    .thumb_func
HardFault:
    tst lr, #4
    ite eq
    mrseq r0, msp
    mrsne r0, psp
    ldr r1, =_stack_start
    msr msp, r1
    b {handler}
    .ltorg
